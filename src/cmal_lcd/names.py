"""One validator for every name that becomes part of a path or a command line.

Method, model, route, condition, pair and sweep names end up in file names
(``data/evaluation/<method>/pr/<route>/<pair>.csv``), in DVC's shell commands
(``--method ${item.method}`` in ``dvc.yaml``) and in Hydra overrides. A name is accepted only
when it matches the conservative pattern :data:`NAME_PATTERN` (letters, digits, ``_ . -``; it
starts with a letter or digit; at most 64 characters; no ``..``), so it can never carry a
shell metacharacter, a path separator or a parent reference. A drive name is a
``route/condition`` pair of such names.

Where a name becomes a file, :func:`output_path` also resolves the path and checks that it
stays under its output root (defence in depth: a name that passed the pattern cannot escape,
and a symlink planted in the output folder cannot redirect the write).

Every error is a :class:`NameError_` (a ``ValueError``) whose one-line message names the key
or file and the bad value.
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

#: A safe name: starts with a letter or digit, then letters, digits, ``_``, ``.``, ``-``;
#: 1 to 64 characters.
NAME_PATTERN = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}")

#: Text shown in error messages.
NAME_RULE = "letters, digits, '_', '.', '-' (starting with a letter or digit, at most 64, no '..')"


class InvalidNameError(ValueError):
    """A name that could reach a path or a command line is not safe."""


class OutsideOutputRootError(ValueError):
    """An output path resolves outside its output root."""


def is_safe_name(name: Any) -> bool:
    """Whether ``name`` is a string matching :data:`NAME_PATTERN` without ``..``."""
    return (isinstance(name, str) and NAME_PATTERN.fullmatch(name) is not None
            and ".." not in name)


def check_name(name: Any, *, key: str) -> str:
    """Return ``name`` when it is safe, else raise naming ``key`` and the value.

    Parameters
    ----------
    name : Any
        The value to check.
    key : str
        Where it came from, e.g. ``methods[2]`` or ``<dir>/dataset.json: pairs[0][3]``.

    Raises
    ------
    InvalidNameError
        ``<key>: unsafe name '<value>'; use <rule>``.
    """
    if not is_safe_name(name):
        raise InvalidNameError(f"{key}: unsafe name {name!r}; use {NAME_RULE}")
    return name


def check_drive_name(name: Any, *, key: str) -> str:
    """Return a drive name ``route/condition`` when both parts are safe names.

    Raises
    ------
    InvalidNameError
        When ``name`` is not exactly two safe names joined by one ``/``.
    """
    parts = name.split("/") if isinstance(name, str) else []
    if len(parts) != 2 or not all(is_safe_name(p) for p in parts):
        raise InvalidNameError(f"{key}: unsafe drive name {name!r}; expected route/condition, "
                               f"each part {NAME_RULE}")
    return name


def check_names(names: Iterable[Any] | None, *, key: str) -> None:
    """Check every item of a list of names (``None`` is accepted: nothing to check)."""
    if names is None:
        return
    for i, name in enumerate(names):
        check_name(name, key=f"{key}[{i}]")


def check_keys(mapping: Mapping | None, *, key: str) -> None:
    """Check every key of a mapping whose keys are names (``None``: nothing to check)."""
    if mapping is None:
        return
    for name in mapping.keys():
        check_name(name, key=f"{key}.{name}" if isinstance(name, str) else key)


def output_path(root: str | os.PathLike, *parts: str) -> Path:
    """``root / parts...``, refused when it resolves outside ``root``.

    Parameters
    ----------
    root : path-like
        The output root (it need not exist yet).
    *parts : str
        Path components below the root (names from config or data).

    Returns
    -------
    Path
        ``Path(root, *parts)`` (not resolved: relative roots stay relative).

    Raises
    ------
    OutsideOutputRootError
        ``<path>: resolves to <resolved>, outside the output folder <root>``.
    """
    path = Path(root, *parts)
    resolved_root = Path(root).resolve()
    resolved = path.resolve()
    if resolved != resolved_root and resolved_root not in resolved.parents:
        raise OutsideOutputRootError(f"{path}: resolves to {resolved}, outside the output "
                                     f"folder {resolved_root}")
    return path


# ------------------------------------------------------------------------------ config


def _select(cfg: Any, dotted: str) -> Any:
    """``cfg.a.b``, or ``None`` when a key on the way is missing or the value is ``???``."""
    from omegaconf import DictConfig, OmegaConf

    if isinstance(cfg, DictConfig):
        return OmegaConf.select(cfg, dotted, default=None, throw_on_missing=False)
    node = cfg
    for part in dotted.split("."):
        if not isinstance(node, Mapping):
            return None
        node = node.get(part)
    return node


def _as_names(value: Any) -> list:
    """A list of names from a list, a mapping (its keys) or a single name."""
    if value is None:
        return []
    if isinstance(value, str):
        return [value]
    if isinstance(value, Mapping) or hasattr(value, "keys"):
        return list(value.keys())
    return list(value)


def check_config_names(cfg: Any) -> None:
    """Check every name of a composed config that reaches a path or a command line.

    Checked keys (each when present): ``methods``, ``model_names``, ``extractors`` (keys),
    ``data.conditions``
    (list or mapping keys), ``data.test.route``, ``data.test.reference``, ``data.test.query``,
    ``data.test.routes`` and ``data.test.validation_routes`` (keys), ``data.test.windows``
    (keys), ``data.test.pairs`` (every condition of every pair).

    Raises
    ------
    InvalidNameError
        Naming the first bad key and its value.
    """
    for key in ("methods", "model_names", "extractors", "data.conditions", "data.test.routes",
                "data.test.validation_routes", "data.test.windows"):
        value = _select(cfg, key)
        if isinstance(value, Mapping) or hasattr(value, "keys"):
            check_keys(value, key=key)
        else:
            check_names(_as_names(value), key=key)
    for key in ("data.test.route", "data.test.reference", "data.test.query"):
        value = _select(cfg, key)
        if value is not None:
            check_name(value, key=key)
    pairs = _select(cfg, "data.test.pairs")
    for i, pair in enumerate(pairs or []):
        check_names(_as_names(pair), key=f"data.test.pairs[{i}]")


# ------------------------------------------------------------------------------ dataset.json


def check_dataset_names(meta: Mapping[str, Any], *, where: str) -> None:
    """Check the names a ``dataset.json`` holds: conditions, routes, drives and pairs.

    Parameters
    ----------
    meta : mapping
        The ``dataset.json`` content.
    where : str
        The file (or caller) named in errors.

    Raises
    ------
    InvalidNameError
        ``<where>: pairs[0][3]: unsafe name '../../../x'; ...``.
    """
    for key in ("conditions", "routes", "validation_routes"):
        check_names(meta.get(key), key=f"{where}: {key}")
    for i, drive in enumerate(meta.get("drives") or []):
        name = drive.get("name") if isinstance(drive, Mapping) else drive
        check_drive_name(name, key=f"{where}: drives[{i}]")
    for key in ("pairs", "validation_pairs", "loops"):
        for i, pair in enumerate(meta.get(key) or []):
            check_pair(pair, key=f"{where}: {key}[{i}]")


def check_pair(pair: Any, *, key: str) -> None:
    """A pair ``[route, reference_drive, query_drive, name]`` of safe names.

    Raises
    ------
    InvalidNameError
        When the pair has another shape or holds an unsafe name.
    """
    if isinstance(pair, str) or not hasattr(pair, "__len__") or len(pair) != 4:
        raise InvalidNameError(f"{key}: expected [route, reference_drive, query_drive, name], "
                               f"got {pair!r}")
    route, reference, query, name = pair
    check_name(route, key=f"{key}[0]")
    check_drive_name(reference, key=f"{key}[1]")
    check_drive_name(query, key=f"{key}[2]")
    check_name(name, key=f"{key}[3]")
