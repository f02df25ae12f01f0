"""The ``cmal-lcd`` command: one module per sub-command, each argparse -> one library call.

- ``cmal-lcd match REFERENCE QUERY``: loop closure between two folders of frames or two
  descriptor files (a user's own data) on the ``evaluate`` stage's path: features, the method's
  matching protocol, SeqSLAM with the paper's Table I parameters, metrics, figures
  (:mod:`cmal_lcd.commands.match`).
- ``cmal-lcd loops FOLDER``: loop closures within one folder (:mod:`cmal_lcd.commands.loops`).
- ``cmal-lcd compose-params [OVERRIDES...]``: write ``params.yaml`` from ``conf/``
  (:mod:`cmal_lcd.commands.params`).
- ``cmal-lcd aggregate SWEEP_DIR --name NAME`` and ``cmal-lcd seeds-report NAME=SWEEP ...``:
  sweep reports (:mod:`cmal_lcd.commands.reports`).
- ``cmal-lcd verify-manifest MANIFEST TARGET`` (:mod:`cmal_lcd.commands.manifest`).

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

# named, not __name__: that is "__main__" under `python -m cmal_lcd.commands`
logger = logging.getLogger("cmal_lcd.commands")

def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``cmal-lcd``; returns the process exit code."""
    from cmal_lcd.commands.arguments import config_overrides

    try:
        parser = build_parser(config_overrides(argv))
    except ValueError as exc:  # a broken conf/ file or --config the option defaults come from
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
    """Entry point of the installed ``cmal-lcd`` script and of ``python -m cmal_lcd.commands``.

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


def build_parser(config: Sequence[str] = ()) -> argparse.ArgumentParser:
    """The ``cmal-lcd`` parser with every sub-command; ``config``: the ``--config`` overrides
    that give ``match`` and ``loops`` their defaults (:func:`cmal_lcd.config.command_matching`).
    """
    parser = OneLineParser(
        prog="cmal-lcd",
        description="CMAL loop closure detection: matching, pipeline helpers.")
    parser.add_argument("-v", "--verbose", action="store_true",
                        help="log progress; on failure, print the traceback too")
    parser.add_argument("--version", action=_VersionAction)
    subparsers = parser.add_subparsers(title="commands", metavar="COMMAND", dest="command")
    from cmal_lcd.commands.loops import add_loops_parser
    from cmal_lcd.commands.manifest import add_verify_manifest_parser
    from cmal_lcd.commands.match import add_match_parser
    from cmal_lcd.commands.params import add_compose_params_parser
    from cmal_lcd.commands.reports import add_aggregate_parser, add_seeds_report_parser
    from cmal_lcd.config import command_matching

    matching = command_matching(config)
    add_match_parser(subparsers, matching)  # cmal-lcd match REFERENCE_DIR QUERY_DIR
    add_compose_params_parser(subparsers)
    add_aggregate_parser(subparsers)
    add_seeds_report_parser(subparsers)
    add_loops_parser(subparsers, matching)  # cmal-lcd loops FOLDER (issue 15)
    add_verify_manifest_parser(subparsers)  # cmal-lcd verify-manifest MANIFEST TARGET
    return parser


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
