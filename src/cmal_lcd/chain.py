"""The chain, read from ``dvc.yaml``: the one declaration of its stages.

``dvc repro`` runs ``dvc.yaml``; the Hydra app (:mod:`cmal_lcd.app`) reads the same file and
runs the same commands in-process, in its job folder: each stage's ``cli`` on the arguments of
its ``cmd``, for the matrix items of the job's own config. Nothing here lists the stages, their
order, their command-line paths or their outputs again.

- A stage's ``cmd`` is ``${py} cmal_lcd.stages.<module> --params params.yaml --flag path ...``
  (``py`` is a ``vars`` entry ending in ``python -m``).
- A ``matrix`` of one key (``method: ${methods}``, ``model: ${model_names}``), or a ``foreach``
  over ``${feature_inputs}`` (one entry per method), makes one run per item. The item is passed
  as ``--<key> <item>`` (under DVC the stage reads it from ``$DVC_STAGE``; either way
  :func:`cmal_lcd.stages.stage_item` checks it).
- ``${item.<key>}``, ``${key}`` and the string ``vars`` are resolved as DVC resolves them.
- A stage's ``params`` are the config keys its ``main`` gets (:func:`declared_params`,
  :func:`cmal_lcd.stages.config_slice`): the one list of what a stage reads.
"""

from __future__ import annotations

import re
import shlex
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import yaml

#: The matrix key of a ``foreach`` stage (one run per method, over ``feature_inputs``).
FOREACH_KEY = "method"


@dataclass(frozen=True)
class StageRun:
    """One run of a ``dvc.yaml`` stage (one matrix item, or the stage itself).

    Attributes
    ----------
    name : str
        The stage's name in ``dvc.yaml`` (``train``).
    item : str or None
        The matrix item (``cmal``), None for a stage without a matrix.
    module : str
        The module its ``cmd`` runs (``cmal_lcd.stages.train``).
    argv : tuple of str
        The ``cmd``'s arguments after the module, resolved, then ``--<key> <item>``.
    outs : tuple of str
        Its ``outs`` and ``metrics``, resolved, relative to the repository (or job) root.
    deps : tuple of str
        Its ``deps``, resolved.
    """

    name: str
    item: str | None
    module: str
    argv: tuple[str, ...]
    outs: tuple[str, ...]
    deps: tuple[str, ...]

    @property
    def address(self) -> str:
        """DVC's name of the run: ``train@cmal``, or ``report``."""
        return self.name if self.item is None else f"{self.name}@{self.item}"


def read_stages(dvc_yaml: str | Path) -> tuple[dict[str, dict], dict[str, str]]:
    """The stages of ``dvc_yaml`` in its order (a ``foreach`` stage as its ``do`` template plus
    ``foreach``), and its string ``vars`` (``py``)."""
    spec = yaml.safe_load(Path(dvc_yaml).read_text(encoding="utf-8"))
    stages = {name: ({**stage["do"], "foreach": stage["foreach"]} if "do" in stage else stage)
              for name, stage in spec["stages"].items()}
    variables: dict[str, str] = {}
    for entry in spec.get("vars", []):
        if isinstance(entry, dict):
            variables.update({k: str(v) for k, v in entry.items()})
    return stages, variables


def matrix_key(stage: Mapping[str, Any]) -> str | None:
    """``method``, ``model`` (the key of the stage's one-key ``matrix``; ``method`` for a
    ``foreach`` stage) or None."""
    if "foreach" in stage:
        return FOREACH_KEY
    keys = list(stage.get("matrix") or {})
    if len(keys) > 1:
        raise ValueError(f"dvc.yaml: a stage's matrix has one key here, got {keys}")
    return keys[0] if keys else None


def resolve(text: str, *, item: str | None, variables: Mapping[str, str],
            feature_inputs: Mapping[str, Mapping] | None = None) -> str:
    """``text`` with ``${var}``, ``${item.<key>}`` and ``${key}`` substituted as DVC does for
    one matrix entry (for a ``foreach`` entry, ``${item.file}`` and ``${item.params.<i>}`` from
    the method's ``feature_inputs``)."""
    for key, value in variables.items():
        text = text.replace("${%s}" % key, value)
    own = (feature_inputs or {}).get(item) if item is not None else None
    if own is not None:
        text = text.replace("${item.file}", str(own["file"]))
        text = re.sub(r"\$\{item\.params\.(\d+)\}", lambda m: str(own["params"][int(m[1])]),
                      text)
    return re.sub(r"\$\{(item\.\w+|key)\}", str(item), text)


def command(cmd: str) -> tuple[str, list[str]]:
    """``(module, argv)`` of a resolved ``cmd``: what follows ``python -m``."""
    tokens = shlex.split(cmd)
    if "-m" not in tokens:
        raise ValueError(f"dvc.yaml: expected a `python -m <module> ...` command, got {cmd!r}")
    at = tokens.index("-m")
    return tokens[at + 1], tokens[at + 2:]


def module_of(stage: Mapping[str, Any], variables: Mapping[str, str]) -> str:
    """The module a stage's ``cmd`` runs (``cmal_lcd.stages.train``)."""
    return command(resolve(stage["cmd"], item=None, variables=variables))[0]


def out_path(entry: Any) -> str:
    """An ``outs``/``metrics`` entry's path (a string, or a one-key dict with its options)."""
    return entry if isinstance(entry, str) else next(iter(entry))


def stage_run(name: str, stage: Mapping[str, Any], item: str | None, *,
              variables: Mapping[str, str],
              feature_inputs: Mapping[str, Mapping] | None = None) -> StageRun:
    """One run of ``stage`` for ``item`` (None for a stage without a matrix)."""
    def fill(text: str) -> str:
        return resolve(text, item=item, variables=variables, feature_inputs=feature_inputs)

    module, argv = command(fill(stage["cmd"]))
    key = matrix_key(stage)
    if key is not None:
        argv += [f"--{key}", str(item)]
    outs = tuple(fill(out_path(o)) for o in [*stage.get("outs", []), *stage.get("metrics", [])])
    deps = tuple(fill(d) for d in stage.get("deps", []) if isinstance(d, str))
    return StageRun(name, item, module, tuple(argv), outs, deps)


def stage_runs(dvc_yaml: str | Path, items: Mapping[str, Sequence[str]], *,
               feature_inputs: Mapping[str, Mapping] | None = None,
               names: Sequence[str] | None = None) -> list[StageRun]:
    """The runs of ``dvc_yaml``'s stages (those in ``names``, default all), in its order.

    Parameters
    ----------
    items : mapping
        The items of each matrix key: ``{"method": [...], "model": [...]}``.
    feature_inputs : mapping, optional
        ``feature_inputs`` of the config (what a ``foreach`` stage's ``${item.file}`` is).
    """
    stages, variables = read_stages(dvc_yaml)
    runs = []
    for name, stage in stages.items():
        if names is not None and name not in names:
            continue
        key = matrix_key(stage)
        for item in ([None] if key is None else items[key]):
            runs.append(stage_run(name, stage, item, variables=variables,
                                  feature_inputs=feature_inputs))
    return runs


def stage_module(dvc_yaml: str | Path, name: str) -> str:
    """The module stage ``name`` of ``dvc_yaml`` runs (``cmal_lcd.stages.train``)."""
    stages, variables = read_stages(dvc_yaml)
    return module_of(stages[name], variables)


def declared_params(dvc_yaml: str | Path, module: str, item: str | None = None,
                    item_inputs: Callable[[str], Mapping] | None = None
                    ) -> tuple[str, ...] | None:
    """The ``params`` of the stage of ``dvc_yaml`` that runs ``module``
    (``cmal_lcd.stages.train``), resolved for matrix item ``item``; None where it declares the
    whole ``params.yaml``. ``item_inputs(item)`` gives a ``foreach`` stage's entry for the item
    (``{"file": ..., "params": [...]}``, what ``feature_inputs`` holds for it), asked only when
    an entry names ``${item.file}`` or ``${item.params.<i>}``.

    Raises
    ------
    ValueError
        When no stage runs ``module``, or a params entry names a file other than
        ``params.yaml``.
    """
    stages, variables = read_stages(dvc_yaml)
    name = next((n for n, stage in stages.items()
                 if module_of(stage, variables) == module),
                None)
    if name is None:
        raise ValueError(f"{dvc_yaml}: no stage runs {module}")
    entries = stages[name].get("params", [])
    own = [e for e in entries if isinstance(e, str) and re.search(r"\$\{item\.(file|params)", e)]
    inputs = {item: item_inputs(item)} if own and item is not None and item_inputs else None
    keys: list[str] = []
    for entry in entries:
        if isinstance(entry, str):
            key = resolve(entry, item=item, variables=variables, feature_inputs=inputs)
            if "${" in key:
                raise ValueError(f"{dvc_yaml}: stage {name}: cannot resolve {entry} for "
                                 f"{item!r}")
            keys.append(key)
            continue
        ((file, listed),) = entry.items()
        if file != "params.yaml":
            raise ValueError(f"{dvc_yaml}: stage {name} reads params from {file}; the stages "
                             f"read params.yaml only")
        if listed is None:
            return None
        keys += listed
    return tuple(dict.fromkeys(keys))


def stage_names(dvc_yaml: str | Path) -> list[str]:
    """The names of ``dvc_yaml``'s stages, in its order."""
    return list(read_stages(dvc_yaml)[0])


def under(path: str | Path, folder: str | Path) -> bool:
    """``path`` is ``folder`` or lies inside it (relative paths, compared by parts)."""
    path, folder = Path(path), Path(folder)
    return path == folder or folder in path.parents
