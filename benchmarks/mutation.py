"""Mutation testing of the numerics and the objective with mutmut (on demand; not in CI).

mutmut changes one small thing at a time in the source (``<`` into ``<=``, ``+`` into ``-``,
a constant, a keyword argument...) and runs the tests that cover the changed function; a
mutant that no test notices *survives*. This script prints the survivors (with their diffs)
and the survival rate, so each can be killed by a test or explained in ``docs/testing.md``.

It never touches the checkout: it copies ``src/``, ``tests/``, ``conf/``, ``benchmarks/``
(``tests/matching`` compares the library with the benchmark's NumPy baseline) and
``pyproject.toml`` into a scratch folder (default ``/tmp/cmal-lcd-mutation``), writes mutmut's
config (``setup.cfg``, section ``[mutmut]``) there and runs ``mutmut run`` in it.

Usage (install the tool with ``pip install -e '.[mutation]'``)::

    # everything the issue asks for (slow: hours on 2 cores)
    python benchmarks/mutation.py
    # one file with its own tests (what docs/testing.md records)
    python benchmarks/mutation.py --mutate 'src/cmal_lcd/evaluation/metrics.py' \\
        --tests tests/evaluation/test_metrics.py --max-children 1

Defaults: ``src/cmal_lcd/matching/*``, ``src/cmal_lcd/evaluation/*`` and the loss functions in
``src/cmal_lcd/models`` (``base.py``, ``cmal.py``, ``bigan.py``), against ``tests/matching``,
``tests/evaluation``, ``tests/models`` and ``tests/stages/test_evaluate.py``.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[1]
DEFAULT_MUTATE = ["src/cmal_lcd/matching/*", "src/cmal_lcd/evaluation/*",
                  "src/cmal_lcd/models/base.py", "src/cmal_lcd/models/cmal.py",
                  "src/cmal_lcd/models/bigan.py"]
DEFAULT_TESTS = ["tests/matching", "tests/evaluation", "tests/models",
                 "tests/stages/test_evaluate.py"]
#: mutmut's exit-code meanings, as ``mutmut results --all`` names them.
SURVIVING = ("survived", "no tests")


def write_config(workdir: Path, mutate: list[str], tests: list[str]) -> None:
    lines = ["[mutmut]", "source_paths = src", "only_mutate ="]
    lines += [f"    {p}" for p in mutate]
    lines += ["pytest_add_cli_args_test_selection ="] + [f"    {t}" for t in tests]
    lines += ["pytest_add_cli_args =", "    -p", "    no:cacheprovider", "    -q",
              "also_copy =", "    conf", "    benchmarks", "use_git_change_detection = false", ""]
    (workdir / "setup.cfg").write_text("\n".join(lines))


def prepare(workdir: Path, mutate: list[str], tests: list[str], *, fresh: bool) -> None:
    if fresh and workdir.exists():
        shutil.rmtree(workdir)
    workdir.mkdir(parents=True, exist_ok=True)
    for name in ("src", "tests", "conf", "benchmarks"):
        shutil.copytree(REPO_ROOT / name, workdir / name, dirs_exist_ok=True,
                        ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    shutil.copy2(REPO_ROOT / "pyproject.toml", workdir / "pyproject.toml")
    write_config(workdir, mutate, tests)


def results(workdir: Path) -> dict[str, str]:
    """``{mutant name: status}`` for every mutant mutmut made."""
    out = subprocess.run(["mutmut", "results", "--all", "true"], cwd=workdir, check=True,
                         capture_output=True, text=True).stdout
    statuses = {}
    for line in out.splitlines():
        if ":" in line and line.startswith("    "):
            name, status = line.strip().rsplit(": ", 1)
            statuses[name] = status
    return statuses


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mutate", nargs="+", default=DEFAULT_MUTATE,
                        help="glob patterns of the files to mutate (relative to the repo)")
    parser.add_argument("--tests", nargs="+", default=DEFAULT_TESTS,
                        help="pytest paths run against each mutant")
    parser.add_argument("--workdir", type=Path, default=Path("/tmp/cmal-lcd-mutation"))
    parser.add_argument("--max-children", type=int, default=1,
                        help="parallel mutants (the dev machine has 2 shared cores)")
    parser.add_argument("--keep", action="store_true",
                        help="reuse the workdir's earlier results (mutmut skips done mutants)")
    parser.add_argument("--no-diffs", action="store_true", help="list survivors without diffs")
    parser.add_argument("--json", type=Path, default=None, help="also write the counts here")
    args = parser.parse_args(argv)

    if shutil.which("mutmut") is None:
        print("mutmut is not installed: pip install -e '.[mutation]'", file=sys.stderr)
        return 2
    prepare(args.workdir, args.mutate, args.tests, fresh=not args.keep)
    # mutmut forks one child per mutant from a process whose numba kernels already ran; numba's
    # default threading layer here (GNU OpenMP) then kills the child with SIGTERM, which mutmut
    # files as "suspicious". The workqueue layer survives the fork. (mutmut's fork-server
    # isolation is no way out: it filed as survived a mutant that its tests kill.)
    env = {**os.environ, "NUMBA_THREADING_LAYER": "workqueue"}
    run = subprocess.run(["mutmut", "run", "--max-children", str(args.max_children)],
                         cwd=args.workdir, env=env)
    if run.returncode not in (0, 1):
        print(f"mutmut run failed (exit {run.returncode})", file=sys.stderr)
        return run.returncode
    statuses = results(args.workdir)
    counts: dict[str, int] = {}
    for status in statuses.values():
        counts[status] = counts.get(status, 0) + 1
    survivors = sorted(n for n, s in statuses.items() if s in SURVIVING)
    total = len(statuses)
    print(f"\n{total} mutants: " + ", ".join(f"{v} {k}" for k, v in sorted(counts.items())))
    if total:
        print(f"survival rate: {len(survivors)}/{total} = {len(survivors) / total:.1%}")
    print(f"\nsurviving mutants ({len(survivors)}):")
    for name in survivors:
        if args.no_diffs:
            print(f"  {name}: {statuses[name]}")
        else:
            subprocess.run(["mutmut", "show", name], cwd=args.workdir)
    if args.json:
        args.json.write_text(json.dumps({"counts": counts, "survivors": survivors,
                                         "total": total}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
