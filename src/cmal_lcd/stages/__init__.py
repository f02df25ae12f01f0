"""The pipeline's stages: one thin command per DVC stage over the library.

Every stage module has ``main(cfg, ...)`` (what tests and the Hydra app call) and a
``cli(argv)`` built from :func:`stage_parser` and :func:`stage_config`, run by
``python -m cmal_lcd.stages.<name>`` through :func:`run`: one log format for every stage, the
config read from ``--params`` (``params.yaml``), and a failure reported as one line with exit
code 2 (:func:`cmal_lcd.errors.run_stage`).
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path
from typing import Any, Callable, NoReturn

#: The log line of every stage (and of ``cmal-lcd``).
LOG_FORMAT = "%(asctime)s %(levelname)s %(name)s: %(message)s"


def stage_parser(doc: str) -> argparse.ArgumentParser:
    """An argument parser described by the first line of ``doc``, with ``--params``."""
    parser = argparse.ArgumentParser(description=doc.strip().splitlines()[0])
    parser.add_argument("--params", default="params.yaml", type=Path,
                        help="the composed config (default: params.yaml)")
    return parser


def method_stage_parser(doc: str, *, out_root: str) -> argparse.ArgumentParser:
    """:func:`stage_parser` plus the paths of a stage that scores one method's features:
    ``--method``, ``--dataset``, ``--features``, ``--protocol``, ``--out`` (default
    ``<out_root>/<method>``); :func:`method_paths` fills the defaults in."""
    parser = stage_parser(doc)
    parser.add_argument("--method", required=True)
    parser.add_argument("--dataset", default="data/dataset", type=Path)
    parser.add_argument("--features", default=None, type=Path,
                        help="default: data/features/<method>")
    parser.add_argument("--protocol", default=None, type=Path,
                        help="default: data/protocol/<method>.json")
    parser.add_argument("--out", default=None, type=Path, help=f"default: {out_root}/<method>")
    parser.set_defaults(out_root=out_root)
    return parser


def method_paths(args: argparse.Namespace) -> dict[str, Any]:
    """``method, dataset_dir, features_dir, protocol_path, out_dir`` of
    :func:`method_stage_parser`'s arguments, defaults filled in."""
    return {"method": args.method, "dataset_dir": args.dataset,
            "features_dir": args.features or Path("data/features") / args.method,
            "protocol_path": args.protocol or Path("data/protocol") / f"{args.method}.json",
            "out_dir": args.out or Path(args.out_root) / args.method}


def stage_config(args: argparse.Namespace) -> Any:
    """Start logging in :data:`LOG_FORMAT` and read the config of ``args.params``."""
    from cmal_lcd.config import load_params

    logging.basicConfig(level=logging.INFO, format=LOG_FORMAT)
    return load_params(args.params)


def run(cli: Callable[[list[str] | None], object]) -> NoReturn:
    """``sys.exit`` with the stage's exit code: 0, or 2 after a one-line failure."""
    from cmal_lcd.errors import run_stage

    sys.exit(run_stage(cli))
