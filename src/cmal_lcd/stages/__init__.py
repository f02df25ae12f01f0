"""The pipeline's stages: one thin command per DVC stage over the library.

Every stage module has ``main(cfg, ...)`` (what tests and the Hydra app call) and a
``cli(argv)`` built from :func:`stage_parser` and :func:`stage_config`, run by
``python -m cmal_lcd.stages.<name>`` through :func:`run`: one log format for every stage, the
config read from ``--params`` (``params.yaml``), and a failure reported as one line with exit
code 2 (:func:`cmal_lcd.errors.run_stage`).

Which config keys a stage's ``main`` reads is its ``params`` in ``dvc.yaml``, the one list
(:func:`cmal_lcd.chain.declared_params`, resolved for the matrix item). A stage module may add
``NOT_INPUTS``: keys it also reads that cannot change its outputs, each with the reason (a
thread count), left out of ``dvc.yaml`` so that changing them re-runs nothing.

``main`` gets only those keys (:func:`config_slice`, from the stage's ``cli`` and from the Hydra
app alike): a read of any other key fails, naming it, instead of depending on an undeclared
value.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
from pathlib import Path
from types import ModuleType
from typing import Any, Callable, Iterable, Mapping, NoReturn

from omegaconf import DictConfig, OmegaConf
from cmal_lcd.paths import REPO, ChainPaths

#: The log line of every stage (and of ``cmal-lcd``).
LOG_FORMAT = "%(asctime)s %(levelname)s %(name)s: %(message)s"


def stage_parser(doc: str) -> argparse.ArgumentParser:
    """An argument parser described by the first line of ``doc``, with ``--params`` and
    ``--root``; parse with :func:`parse_stage_args`."""
    parser = argparse.ArgumentParser(description=doc.strip().splitlines()[0])
    parser.add_argument("--params", default=Path("params.yaml"), type=Path,
                        help="the composed config (default: params.yaml)")
    parser.add_argument("--root", default=Path("."), type=Path,
                        help="the folder the relative paths of this command and its defaults "
                             "lie under (default: the working directory, the checkout under "
                             "dvc repro; cmal-lcd-run gives its job folder)")
    return parser


def parse_stage_args(parser: argparse.ArgumentParser,
                     argv: Iterable[str] | None = None) -> argparse.Namespace:
    """``parser``'s arguments with every relative path under ``--root`` (``root / path``; an
    absolute path stays as given), and ``args.paths``: the chain's layout under it
    (:class:`cmal_lcd.paths.ChainPaths`), for the defaults derived from an item.

    The working directory stays the caller's, so a relative path inside the config (a folder
    dataset's ``data.root``, a descriptor file) means what it meant where the command was
    launched; only the chain's own paths move with ``--root``.
    """
    args = parser.parse_args(argv)
    for key, value in vars(args).items():
        if isinstance(value, Path) and key != "root":
            setattr(args, key, args.root / value)
    args.paths = ChainPaths(args.root)
    return args


def method_stage_parser(doc: str, *, out_root: str) -> argparse.ArgumentParser:
    """:func:`stage_parser` plus the paths of a stage that scores one method's features:
    ``--method``, ``--dataset``, ``--features``, ``--protocol``, ``--out`` (default
    ``<out_root>/<method>``); :func:`method_paths` fills the defaults in."""
    parser = stage_parser(doc)
    parser.add_argument("--method", default=None,
                        help="default: the item of the DVC stage running it ($DVC_STAGE)")
    parser.add_argument("--dataset", default=REPO.dataset, type=Path)
    parser.add_argument("--features", default=None, type=Path,
                        help=f"default: {REPO.features}/<method>")
    parser.add_argument("--protocol", default=None, type=Path,
                        help=f"default: {REPO.protocols}/<method>.json")
    parser.add_argument("--out", default=None, type=Path, help=f"default: {out_root}/<method>")
    parser.set_defaults(out_root=Path(out_root))
    return parser


#: Set by DVC for every stage command it runs: the stage's address, ``<stage>@<item>`` for a
#: ``matrix`` or ``foreach`` stage (``train@cmal``; ``dvc.yaml:`` before it outside the root).
DVC_STAGE_ENV = "DVC_STAGE"


def stage_item(given: str | None, *, stage: str, option: str) -> str:
    """``given``, else the item of the DVC stage this command runs as (``$DVC_STAGE``
    ``train@cmal`` -> ``cmal``); a safe name either way (:func:`cmal_lcd.names.check_name`).

    ``dvc.yaml`` pastes no model or method name into a ``cmd``: DVC runs ``cmd`` through a
    shell, so a name written there from ``params.yaml`` (a hand edit, ``dvc exp run -S``)
    would run as shell code before any of our code could refuse it. DVC hands the stage its
    own address instead, and the name is checked here.

    Raises
    ------
    ValueError
        Naming ``option``: not given and not run as a ``<stage>@<item>`` DVC stage, or an
        unsafe name.
    """
    from cmal_lcd.names import check_name

    if given is None:
        address = os.environ.get(DVC_STAGE_ENV, "")
        name, at, item = address.rpartition(":")[2].partition("@")
        if name != stage or not at:
            raise ValueError(f"{option}: not given, and this command is not run by DVC as a "
                             f"{stage}@<name> stage (${DVC_STAGE_ENV}={address!r})")
        given = item
    return check_name(given, key=option)


def method_paths(args: argparse.Namespace) -> dict[str, Any]:
    """``method, dataset_dir, features_dir, protocol_path, out_dir`` of
    :func:`method_stage_parser`'s arguments parsed by :func:`parse_stage_args`
    (``args.method`` already set, see :func:`stage_item`), defaults filled in."""
    return {"method": args.method, "dataset_dir": args.dataset,
            "features_dir": args.features or args.paths.method_features(args.method),
            "protocol_path": args.protocol or args.paths.protocol(args.method),
            "out_dir": args.out or args.out_root / args.method}


def stage_params(stage: ModuleType, item: str | None = None,
                 cfg: Mapping[str, Any] | None = None) -> tuple[str, ...] | None:
    """The config keys ``dvc.yaml`` declares for ``stage`` (a ``cmal_lcd.stages`` module) and
    matrix item ``item``; None for the whole config (:func:`cmal_lcd.chain.declared_params` on
    the checkout's ``dvc.yaml``). A features stage's own slots come from the method's node in
    ``cfg.extractors`` (default: the built-in nodes), as ``feature_inputs`` does at composition
    (:func:`cmal_lcd.features.inputs.method_inputs`), so a method outside ``methods`` runs too.
    """
    from cmal_lcd.chain import declared_params
    from cmal_lcd.checkout import checkout_dvc_yaml

    def item_inputs(method: str) -> Mapping[str, Any]:
        from cmal_lcd.features.inputs import method_inputs

        extractors = cfg.get("extractors") if cfg is not None else None
        if isinstance(extractors, DictConfig):
            extractors = OmegaConf.to_container(extractors, resolve=True)
        return method_inputs(method, extractors)

    return declared_params(checkout_dvc_yaml(), stage.__spec__.name, item, item_inputs)


def stage_keys(stage: ModuleType, item: str | None = None,
               cfg: Mapping[str, Any] | None = None) -> tuple[str, ...] | None:
    """Every config key ``stage``'s ``main`` reads: :func:`stage_params` and the stage's
    ``NOT_INPUTS``; None for the whole config."""
    params = stage_params(stage, item, cfg)
    if params is None:
        return None
    return tuple(dict.fromkeys([*params, *getattr(stage, "NOT_INPUTS", {})]))


#: Marks a key the config lacks (``OmegaConf.select``'s default).
_MISSING = object()


def config_slice(cfg: DictConfig, keys: Iterable[str] | None) -> DictConfig:
    """The part of ``cfg`` under the dotted ``keys`` (``["seed", "matching.ds"]``), in the same
    layout, read-only and closed: reading any other key raises an error naming it. ``keys``
    None gives all of ``cfg``. A key ``cfg`` lacks stays absent, as in ``cfg`` (a partial
    ``params.yaml`` is left to the stage that reads it; the schema checks what is there).
    """
    if keys is None:
        part = OmegaConf.create(OmegaConf.to_container(cfg, resolve=True))
    else:
        part = OmegaConf.create({})
        for key in keys:
            value = OmegaConf.select(cfg, key, default=_MISSING)
            if value is _MISSING:
                continue
            if isinstance(value, DictConfig) or OmegaConf.is_list(value):
                value = OmegaConf.to_container(value, resolve=True)
            OmegaConf.update(part, key, value, merge=True)
    OmegaConf.set_struct(part, True)
    OmegaConf.set_readonly(part, True)
    return part


def stage_config(args: argparse.Namespace, stage: str, item: str | None = None) -> DictConfig:
    """Start logging in :data:`LOG_FORMAT`; read the config of ``args.params`` and return the
    slice stage ``stage`` (its module's ``__name__``) reads for matrix item ``item``."""
    from cmal_lcd.config import load_params

    logging.basicConfig(level=logging.INFO, format=LOG_FORMAT)
    cfg = load_params(args.params)
    return config_slice(cfg, stage_keys(sys.modules[stage], item, cfg))


def run(cli: Callable[[list[str] | None], object]) -> NoReturn:
    """``sys.exit`` with the stage's exit code: 0, or 2 after a one-line failure."""
    from cmal_lcd.errors import run_stage

    sys.exit(run_stage(cli))
