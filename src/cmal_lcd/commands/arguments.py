"""Command-line options shared by several ``cmal-lcd`` commands.

Imports nothing heavy at import time (no torch, no Hydra): ``cmal-lcd --help`` stays fast and
``cmal-lcd match`` with SAD never imports torch.
"""

from __future__ import annotations

import argparse
from collections.abc import Mapping, Sequence
from typing import Any


class DefaultsHelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Defaults in the help of options that take a value, not of on/off flags: argparse would
    print ``--no-enhance ... (default: True)``, the default of ``enhance``, which reads as if the
    flag were on by default."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        if action.nargs == 0 or action.default == []:  # a flag, or a list that starts empty
            return action.help
        return super()._get_help_string(action)


def add_config_argument(parser: argparse.ArgumentParser) -> None:
    """``--config OVERRIDE`` (repeatable): Hydra overrides of ``conf/`` that give the command
    its defaults and its extractor's config (:func:`config_overrides` reads them first)."""
    parser.add_argument("--config", action="append", default=[], metavar="OVERRIDE",
                        help="a Hydra override of conf/, repeatable (e.g. experiment=nordland, "
                             "matching.ds=5): the defaults shown here and the extractor's "
                             "settings then come from conf/ composed with it (with --help: "
                             "shown here)")


def config_overrides(argv: Sequence[str] | None) -> list[str]:
    """The ``--config`` values of a command line, read before the parser is built (they
    change its defaults)."""
    import sys

    early = argparse.ArgumentParser(add_help=False)
    early.add_argument("--config", action="append", default=[])
    known, _ = early.parse_known_args(sys.argv[1:] if argv is None else list(argv))
    return known.config


def add_seqslam_arguments(parser: argparse.ArgumentParser, *, conf: Mapping[str, Any],
                          ds_help: str, r_window_help: str, enhance_help: str,
                          score_help: str) -> None:
    """Add SeqSLAM's options, their defaults from the ``matching`` node ``conf``
    (:func:`cmal_lcd.config.command_matching`; paper Table I): ``--ds``, ``--v-min``,
    ``--v-max``, ``--v-step``, ``--r-window``, ``--no-enhance`` (``enhance``) and ``--score``.

    The help texts that differ between commands (what a frame is, which protocol an option
    applies to) are given by the caller.
    """
    from cmal_lcd.matching import SeqSLAMParams
    from cmal_lcd.schema import MatchingSchema

    d = SeqSLAMParams.from_config(conf)
    parser.add_argument("--ds", type=int, default=d.ds, help=ds_help)
    parser.add_argument("--v-min", type=float, default=d.v_min,
                        help="slowest trajectory velocity")
    parser.add_argument("--v-max", type=float, default=d.v_max,
                        help="fastest trajectory velocity")
    parser.add_argument("--v-step", type=float, default=d.v_step, help="velocity step")
    parser.add_argument("--r-window", type=int, default=d.r_window, help=r_window_help)
    parser.add_argument("--no-enhance", dest="enhance", action="store_false",
                        default=d.enhance, help=enhance_help)
    parser.add_argument("--score", choices=_choices(MatchingSchema, "score"), default=d.score,
                        help=score_help)


def seqslam_params(args: argparse.Namespace):
    """:class:`~cmal_lcd.matching.SeqSLAMParams` from the options of
    :func:`add_seqslam_arguments`; an invalid value is one line naming its option
    (``--ds: must be >= 1, got 0``; the check is the ``matching`` schema's)."""
    from cmal_lcd.matching import SeqSLAMParams

    try:
        return SeqSLAMParams(ds=args.ds, v_min=args.v_min, v_max=args.v_max, v_step=args.v_step,
                             r_window=args.r_window, enhance=args.enhance, score=args.score)
    except ValueError as exc:
        field, _, what = str(exc).partition(": ")
        raise ValueError(f"--{field.replace('_', '-')}: {what}") from None


def _choices(schema_type: type, name: str) -> tuple:
    """The allowed values of a schema field (its ``choices`` rule)."""
    import dataclasses

    return tuple(next(f for f in dataclasses.fields(schema_type)
                      if f.name == name).metadata["choices"])
