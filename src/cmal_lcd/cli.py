"""The ``cmal-lcd`` command.

Sub-commands (one small function each, ``main(argv)`` dispatches):

- ``cmal-lcd match REFERENCE_DIR QUERY_DIR``: loop closure between two folders of frames (a
  user's own data), on the ``evaluate`` stage's path: features, the method's matching
  protocol, SeqSLAM with the paper's Table I parameters, metrics, figures
  (:mod:`cmal_lcd.match_command`).
- ``cmal-lcd loops FOLDER``: loop closures within one folder (:mod:`cmal_lcd.loops_command`).
- ``cmal-lcd compose-params [OVERRIDES...]``: write ``params.yaml`` from ``conf/`` (what DVC
  reads), e.g. ``cmal-lcd compose-params experiment=paper``.
- ``cmal-lcd aggregate SWEEP_DIR --name NAME``: a Hydra sweep folder -> ``reports/sweeps/NAME/``.

A failure is one line on stderr, ``cmal-lcd <command>: error: <message naming the file, folder
or key>``, with exit code 2 (:mod:`cmal_lcd.errors`); ``cmal-lcd --verbose`` adds the traceback.

The argparse namespace stops at the sub-command function, which calls a plain function with
explicit arguments. Imports stay inside the functions: ``cmal-lcd --help`` stays fast.
"""

from __future__ import annotations

import argparse
import gc
import logging
import sys
from collections.abc import Sequence
from pathlib import Path

# named, not __name__: that is "__main__" under `python -m cmal_lcd.cli`
logger = logging.getLogger("cmal_lcd.cli")


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``cmal-lcd``; returns the process exit code."""
    try:
        parser = build_parser()
    except ValueError as exc:  # a broken conf/ file the option defaults come from
        print(f"cmal-lcd: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    if not hasattr(args, "func"):
        parser.print_help()
        return 2
    prog = f"cmal-lcd {args.command}" if getattr(args, "command", None) else "cmal-lcd"
    try:
        return args.func(args)
    except KeyboardInterrupt:
        from cmal_lcd.errors import report_interrupt

        return report_interrupt(prog)
    except Exception as exc:  # noqa: BLE001 - the user-facing boundary: one line, exit 2
        from cmal_lcd.errors import report_failure

        return report_failure(prog, exc, verbose=args.verbose)


def console_main() -> int:
    """Entry point of the installed ``cmal-lcd`` script and of ``python -m cmal_lcd.cli``.

    :func:`main`, then :func:`gc.freeze`: the process ends right after, and the interpreter's
    shutdown would otherwise run full garbage collections over every object numba, NumPy and
    the command created (0.22-0.31 s of a 2-3 s ``match``, ``benchmarks/README.md``). Frozen
    objects are still freed with the process; every file a command writes is closed before
    :func:`main` returns. Library callers and tests call :func:`main`, which leaves the
    collector alone.
    """
    load_cython_blas_alone()
    try:
        return main()
    finally:
        gc.freeze()


def load_cython_blas_alone() -> bool:
    """Load ``scipy.linalg.cython_blas`` without the rest of ``scipy.linalg``; whether it did.

    numba's CPU target, set up at the first kernel call of a process, runs ``import
    scipy.linalg.cython_blas`` to learn whether a BLAS is there (``numba.np.linalg.ensure_blas``).
    That statement first runs ``scipy/linalg/__init__.py``, which imports SciPy's whole linear
    algebra API (about 230 modules, 0.12-0.16 s here, ``benchmarks/README.md``) that no
    SeqSLAM kernel uses. Loading the one extension module under its own name beforehand turns
    numba's import into a look-up in :data:`sys.modules`; numba finds the same file, so the same
    BLAS. Only the ``cmal-lcd`` script does this, for the one command its process runs. A later
    ``import scipy.linalg`` still works, and ``from scipy.linalg import cython_blas`` gives this
    module; only the attribute ``scipy.linalg.cython_blas`` stays unset.

    Does nothing (False) when ``scipy.linalg`` is already imported, or SciPy or the module's file
    cannot be found (numba then imports it as usual).
    """
    import importlib.machinery
    import importlib.util

    name = "scipy.linalg.cython_blas"
    if name in sys.modules or "scipy.linalg" in sys.modules:
        return False
    try:
        import scipy
    except ImportError:
        return False
    spec = importlib.machinery.PathFinder.find_spec(name, [str(Path(scipy.__file__).parent
                                                               / "linalg")])
    if spec is None:
        return False
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    try:
        spec.loader.exec_module(module)
    except Exception:  # noqa: BLE001 - leave it to numba's own import, which reports failures
        del sys.modules[name]
        return False
    return True


class OneLineParser(argparse.ArgumentParser):
    """argparse, but a usage error is one line (``cmal-lcd match: error: argument --d-thresh:
    invalid int value: '1e20' (see cmal-lcd match --help)``), exit 2, without the usage block;
    its sub-command parsers are of this class too."""

    def error(self, message: str):
        from cmal_lcd.errors import EXIT_USER_ERROR, printable

        self.exit(EXIT_USER_ERROR, f"{self.prog}: error: {printable(message)} "
                                   f"(see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    """The ``cmal-lcd`` parser with every sub-command."""
    parser = OneLineParser(
        prog="cmal-lcd",
        description="CMAL loop closure detection: matching, pipeline helpers.")
    parser.add_argument("-v", "--verbose", action="store_true",
                        help="log progress; on failure, print the traceback too")
    parser.add_argument("--version", action=_VersionAction)
    subparsers = parser.add_subparsers(title="commands", metavar="COMMAND", dest="command")
    from cmal_lcd.match_command import add_match_parser

    add_match_parser(subparsers)  # cmal-lcd match REFERENCE_DIR QUERY_DIR
    add_compose_params_parser(subparsers)
    add_aggregate_parser(subparsers)
    add_seeds_report_parser(subparsers)
    from cmal_lcd.loops_command import add_loops_parser
    from cmal_lcd.manifest_command import add_verify_manifest_parser

    add_loops_parser(subparsers)  # cmal-lcd loops FOLDER (issue 15)
    add_verify_manifest_parser(subparsers)  # cmal-lcd verify-manifest MANIFEST TARGET
    return parser


# ---------------------------------------------------------------------------- compose-params


def add_compose_params_parser(subparsers) -> argparse.ArgumentParser:
    """``cmal-lcd compose-params [OVERRIDES...] [--output params.yaml]``."""
    p = subparsers.add_parser(
        "compose-params", help="write params.yaml from conf/ (plus Hydra overrides)",
        description="Compose conf/config.yaml with Hydra overrides and write it where DVC "
                    "reads it. Same output as `dvc exp run` with hydra.enabled.")
    p.add_argument("overrides", nargs="*", help="Hydra overrides, e.g. experiment=paper")
    p.add_argument("--output", default=None, type=Path,
                   help="default: params.yaml of the checkout (--repo)")
    p.add_argument("--repo", default=None, type=Path,
                   help="the checkout whose conf/ is composed (default: $CMAL_LCD_REPO, else the "
                        "nearest folder at or above the working directory holding "
                        "conf/config.yaml)")
    p.set_defaults(func=run_compose_params)
    return p


def run_compose_params(args: argparse.Namespace) -> int:
    from cmal_lcd.config import checkout_root, compose_params_yaml

    root = checkout_root(args.repo)
    tracked = root / "params.yaml"
    output = compose_params_yaml(args.overrides, output=args.output or tracked,
                                 config_dir=root / "conf")
    print(f"wrote {output}")
    if Path(output).resolve() == tracked.resolve():
        warning = preset_warning(output)
        if warning:
            print(f"cmal-lcd compose-params: warning: {warning}", file=sys.stderr)
    return 0


def preset_warning(params_file: Path) -> str:
    """One line when ``params_file`` (the checkout's tracked ``params.yaml``) holds a preset:
    ``dvc repro`` would replace the committed results with that run's; empty otherwise."""
    import yaml

    preset = (yaml.safe_load(Path(params_file).read_text()) or {}).get("preset") or {}
    names = [str(preset[k]) for k in ("experiment", "debug") if preset.get(k)]
    if not names:
        return ""
    return (f"params.yaml now holds a {' '.join(names)} config: `dvc repro` will replace the "
            f"committed data/, models/ and reports/ with that run's results (undo: `git checkout "
            f"params.yaml dvc.lock reports && dvc checkout`). A try that touches nothing "
            f"tracked: `cmal-lcd-run {' '.join(names)}` (writes under outputs/).")


# --------------------------------------------------------------------------------- aggregate


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


class _VersionAction(argparse.Action):
    """``--version``: print :func:`_version_text` and exit, looked up only when asked for
    (``importlib.metadata`` costs about 0.1 s at every start otherwise)."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS,
                 help="show program's version number and exit"):
        super().__init__(option_strings, dest=dest, default=default, nargs=0, help=help)

    def __call__(self, parser, namespace, values, option_string=None):
        print(_version_text())
        parser.exit()


def _version_text() -> str:
    """``cmal-lcd X.Y.Z`` (the installed distribution's version, else the package's)."""
    try:
        from importlib.metadata import version

        number = version("cmal-lcd")
    except Exception:  # noqa: BLE001 - not installed (e.g. PYTHONPATH=src): the package's own
        from cmal_lcd import __version__ as number
    return f"cmal-lcd {number}"


if __name__ == "__main__":  # pragma: no cover
    sys.exit(console_main())
