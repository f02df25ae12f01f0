"""User-facing failures: one line naming the file, folder or key, exit code 2.

``cmal-lcd`` sub-commands and the stage modules (``python -m cmal_lcd.stages.X``) end a failed
run with :func:`report_failure`: ``<prog>: error: <message>`` on stderr, exit code
:data:`EXIT_USER_ERROR`, no traceback. ``cmal-lcd --verbose`` (or ``CMAL_LCD_TRACEBACK=1`` for
the stages) prints the traceback as well.
"""

from __future__ import annotations

import os
import sys
import traceback
from collections.abc import Callable, Sequence
from pathlib import Path

#: Exit code of a failure reported as one line (argparse uses 2 for usage errors, too).
EXIT_USER_ERROR = 2

#: Environment variable that makes the stage modules print the traceback of a failure.
TRACEBACK_ENV = "CMAL_LCD_TRACEBACK"


def one_line(exc: BaseException) -> str:
    """The message of ``exc`` on one line, naming the file of an ``OSError``.

    ``OSError(2, 'No such file or directory', '/proc/x')`` becomes
    ``/proc/x: No such file or directory``; a multi-line message is joined with spaces; an
    empty message becomes the exception's type name.
    """
    if isinstance(exc, OSError) and exc.filename is not None and exc.strerror:
        return printable(f"{exc.filename}: {exc.strerror}")
    lines = [line.strip() for line in str(exc).splitlines() if line.strip()]
    return printable(" ".join(lines)) or type(exc).__name__


def printable(text: str) -> str:
    """``text`` with every non-printable character (an escape sequence, a newline in a file
    name) written as its Python escape, ``\\x1b``: a file name cannot spoof the terminal."""
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)


def report_failure(prog: str, exc: BaseException, *, verbose: bool = False) -> int:
    """Print ``<prog>: error: <one line>`` (after the traceback when ``verbose``); return 2."""
    if verbose:
        traceback.print_exception(exc, file=sys.stderr)
    print(f"{prog}: error: {one_line(exc)}", file=sys.stderr)
    return EXIT_USER_ERROR


def run_stage(cli: Callable[[Sequence[str] | None], object],
              argv: Sequence[str] | None = None) -> int:
    """Run a stage's ``cli(argv)``; a failure becomes one line and exit code 2.

    Use as ``sys.exit(run_stage(cli))`` under ``if __name__ == "__main__"``. The program name
    is the stage module (``cmal_lcd.stages.evaluate``); set ``CMAL_LCD_TRACEBACK=1`` to see the
    traceback.
    """
    module = getattr(cli, "__module__", "") or ""
    if module == "__main__":  # python -m cmal_lcd.stages.X: the spec keeps the real name
        spec = getattr(sys.modules["__main__"], "__spec__", None)
        module = spec.name if spec is not None else Path(sys.argv[0]).stem
    try:
        cli(argv)
    except KeyboardInterrupt:
        return report_interrupt(module or "stage")
    except Exception as exc:  # noqa: BLE001 - the user-facing boundary
        verbose = os.environ.get(TRACEBACK_ENV, "") not in ("", "0")
        return report_failure(module or "stage", exc, verbose=verbose)
    return 0


#: The exit code of a command stopped by Ctrl-C (SIGINT), as a shell reports it (128 + 2).
INTERRUPTED = 130


def report_interrupt(prog: str) -> int:
    """One line for a command stopped by Ctrl-C; :data:`INTERRUPTED`. Every output is written
    old-or-new (docs/reliability.md), so what is on disk is the previous result or none."""
    print(f"{prog}: interrupted (Ctrl-C); its outputs are the previous ones or none",
          file=sys.stderr)
    return INTERRUPTED
