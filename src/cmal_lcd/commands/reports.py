"""``cmal-lcd aggregate SWEEP_DIR --name NAME`` (a Hydra sweep folder ->
``reports/sweeps/NAME/``) and ``cmal-lcd seeds-report NAME=SWEEP_DIR ...`` (Table II with 95%
intervals over seeds, ``reports/seeds/``)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

def add_aggregate_parser(subparsers) -> argparse.ArgumentParser:
    """``cmal-lcd aggregate SWEEP_DIR --name NAME [--out reports/sweeps]``."""
    p = subparsers.add_parser(
        "aggregate", help="turn a Hydra sweep folder into reports/sweeps/<name>/",
        description="Collect every job of a `cmal-lcd-run -m ...` sweep (its overrides and "
                    "metrics) into results.csv, figures against each swept number and, when "
                    "seeds were swept, Table II with mean and 95% CI over seeds.")
    p.add_argument("sweep_dir", type=Path, help="e.g. multirun/2026-11-22/10-00-00")
    p.add_argument("--name", required=True,
                   help="folder name under --out (letters, digits, '_', '.', '-')")
    p.add_argument("--out", default=Path("reports/sweeps"), type=Path)
    p.set_defaults(func=run_aggregate)
    return p


def run_aggregate(args: argparse.Namespace) -> int:
    from cmal_lcd.names import check_name, output_path
    from cmal_lcd.reports.sweeps import aggregate_sweep

    out = aggregate_sweep(args.sweep_dir,
                          output_path(args.out, check_name(args.name, key="--name")))
    print(f"wrote {out}")
    return 0


def add_seeds_report_parser(subparsers) -> argparse.ArgumentParser:
    """``cmal-lcd seeds-report NAME=SWEEP_DIR ... --default NAME [--out reports/seeds]``."""
    p = subparsers.add_parser(
        "seeds-report", help="compare CMAL objectives over seeds (validation) and write Table II "
                             "with 95%% CIs",
        description="Each argument NAME=SWEEP_DIR is a seed sweep (`cmal-lcd-run -m "
                    "experiment=seeds objective=NAME ...`). Writes README.md and CSVs: CMAL's "
                    "validation scores per objective, Table II mean [95% CI] over seeds per "
                    "objective, paired differences and invariance.")
    p.add_argument("sweeps", nargs="+", help="objective=sweep folder, e.g. paper=multirun/a")
    p.add_argument("--default", required=True, help="the configuration's default objective")
    p.add_argument("--out", default=Path("reports/seeds"), type=Path)
    p.add_argument("--focus", default="cmal",
                   help="the method whose validation scores and paired differences (against "
                        "every other method of the sweeps) the report gives (default cmal; "
                        "e.g. cmal_place for experiment=place)")
    p.add_argument("--variant", default="selected",
                   help="the test metrics of the tables: selected (default; each method's "
                        "protocol chosen on validation) or strict (the same matches at "
                        "matching.d_thresh_strict)")
    p.set_defaults(func=run_seeds_report)
    return p


def run_seeds_report(args: argparse.Namespace) -> int:
    from cmal_lcd.reports.seeds_report import write_seeds_report
    from cmal_lcd.reports.sweep_jobs import sweep_jobs

    sweeps = {}
    for item in args.sweeps:
        name, sep, folder = item.partition("=")
        if not sep or not name or not Path(folder).is_dir():
            return _refused(f"{item!r}: expected NAME=an existing sweep folder")
        if not sweep_jobs(Path(folder)):
            return _refused(f"{folder}: no job of a sweep in it (no */.hydra/overrides.yaml; "
                            f"a `cmal-lcd-run -m ...` output folder); nothing was written")
        sweeps[name] = Path(folder)
    if args.default not in sweeps:
        return _refused(f"--default {args.default!r}: not one of the sweeps given "
                        f"({', '.join(sweeps)}); nothing was written")
    out = write_seeds_report(sweeps, args.out, default=args.default, focus=args.focus,
                             variant=args.variant)
    print(f"wrote {out}")
    return 0


def _refused(message: str) -> int:
    """Print ``cmal-lcd seeds-report: <message>`` on stderr; exit code 2."""
    print(f"cmal-lcd seeds-report: {message}", file=sys.stderr)
    return 2
