"""End-to-end speed of ``cmal-lcd match`` (SAD) on the Nordland summer / winter frames.

Issue 14, item 2: target at most 2 s wall, end to end, for 3,576 + 3,576 frames of 64 x 32 on
this 2-core machine (unloaded). Each case runs the real command in a fresh process
(``python -m cmal_lcd.commands match REFERENCE QUERY --out ...``, this checkout's ``src`` first on
``PYTHONPATH``) and prints:

- the command's own split from ``metrics.json`` (``timing``: wall, ``timing_cpu``: process CPU
  seconds of all threads): ``decode`` (read and decode both folders), ``features`` (SAD
  thumbnails), ``match`` (``evaluate_pair``: difference matrix, enhancement, sequence search,
  metrics; its wall-time parts ``difference``, ``search`` and ``metrics``, the rest of the
  step), ``figures`` (both PNGs), ``total`` (from the call of ``match_folders`` to the last
  figure, imports made on the way included);
- ``start-up``: process start, ``cmal_lcd.commands`` and parser imports, writing ``metrics.json``
  and swapping the output folder in (end-to-end minus ``total``);
- ``end to end``: wall time of the subprocess, and the CPU time of the child
  (``getrusage(RUSAGE_CHILDREN)``), which on a shared machine says more than wall time.

Cases: ``1800`` (the 1,800 summer frames against the 1,800 winter frames) and ``3600`` (each
season's frames followed by the same frames mirrored left-right: 3,600 + 3,600, the size of the
target; links and mirrored frames in a temporary folder, deleted afterwards).

    .venv/bin/python benchmarks/bench_match.py [--data ../shared/data/nordland_summer_winter]
        [--sizes 1800 3600] [--repeat 1] [--no-figures]

The data set sits beside the checkout (``../shared``); without it the script says so and exits
with code 0. Figures: ``benchmarks/README.md``.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from cmal_lcd.workflows.match_folders import MATCH_PARTS, TIMING_KEYS

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_DATA = ROOT.parent / "shared" / "data" / "nordland_summer_winter"


def season_twice(target: Path, season: Path) -> Path:
    """A folder of 2 x 1,800 frames: the season's frames (symbolic links ``a-<name>``), then
    the same frames mirrored left-right (``b-<name>``, written here): a route twice as long
    whose second half shows other places (a mirrored world), so that frame ``i`` of one
    season's folder is still frame ``i`` of the other's."""
    import cv2

    target.mkdir(parents=True)
    files = sorted(season.glob("*.png"))
    for file in files:
        (target / f"a-{file.name}").symlink_to(file)
    for file in files:
        image = cv2.imread(str(file), cv2.IMREAD_UNCHANGED)
        if image is None or not cv2.imwrite(str(target / f"b-{file.name}"), image[:, ::-1]):
            raise SystemExit(f"{file}: cannot mirror this frame")
    return target


def case_folders(data: Path, size: int, work: Path) -> tuple[Path, Path]:
    """Reference and query folders of a case (``1800`` or ``3600`` frames each)."""
    summer, winter = data / "summer", data / "winter"
    if size == 1800:
        return summer, winter
    if size == 3600:
        return (season_twice(work / "summer", summer), season_twice(work / "winter", winter))
    raise ValueError(f"--sizes: 1800 or 3600, got {size}")


def run_cli(reference: Path, query: Path, out: Path, options: list[str]) -> dict:
    """Run ``cmal-lcd match`` (plus ``options``) in a fresh process; its metrics plus wall and
    CPU seconds."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(
        [str(ROOT / "src")] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep)
                               if p])}
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "cmal_lcd.commands", "match", str(reference),
                           str(query), "--out", str(out), *options], capture_output=True,
                          text=True,
                          env=env, cwd=ROOT)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        raise SystemExit(f"cmal-lcd match failed ({done.returncode}): {done.stderr.strip()}")
    metrics = json.loads((out / "metrics.json").read_text())
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {**metrics, "end_to_end": wall, "end_to_end_cpu": cpu}


def print_case(size: int, run: dict) -> None:
    wall, cpu = run["timing"], run["timing_cpu"]
    rows = []
    for step in TIMING_KEYS:
        if step in wall:
            rows.append((step, wall[step], cpu[step]))
        if step == "match":  # its parts, wall only
            rows += [(f"- {part}", wall[part], None) for part in MATCH_PARTS if part in wall]
    rows.append(("start-up", run["end_to_end"] - wall["total"],
                 run["end_to_end_cpu"] - cpu["total"]))
    rows.append(("end to end", run["end_to_end"], run["end_to_end_cpu"]))
    print(f"\n{size} + {size} frames ({run['n_reference']} x {run['n_query']}), R@100P "
          f"{run['recall_at_100p']:.4f}, AUC-PR {run['auc_pr']:.4f}")
    print("| step | wall s | CPU s |\n|---|---|---|")
    for step, w, c in rows:
        print(f"| {step} | {w:.2f} | {'' if c is None else f'{c:.2f}'} |")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA)
    parser.add_argument("--sizes", type=int, nargs="+", default=[1800, 3600])
    parser.add_argument("--repeat", type=int, default=1, help="runs per size (all printed)")
    parser.add_argument("--no-figures", action="store_true",
                        help="time `match --no-figures` (metrics.json only) instead")
    parser.add_argument("--quantise-sad", action="store_true",
                        help="time `match --quantise-sad` (SAD on one-byte z-scores, sad_u8)")
    args = parser.parse_args(argv)
    if not (args.data / "summer").is_dir() or not (args.data / "winter").is_dir():
        print(f"bench_match: skipped: no Nordland frames at {args.data} (summer/, winter/); "
              f"the data set sits beside the checkout in ../shared")
        return 0
    print(f"nproc {os.cpu_count()}, load average {os.getloadavg()[0]:.2f} at the start")
    with tempfile.TemporaryDirectory(prefix="bench_match-") as tmp:
        for size in args.sizes:
            reference, query = case_folders(args.data, size, Path(tmp) / str(size))
            for i in range(args.repeat):
                options = (["--no-figures"] if args.no_figures else []) + \
                    (["--quantise-sad"] if args.quantise_sad else [])
                print_case(size, run_cli(reference, query, Path(tmp) / f"out-{size}-{i}",
                                         options))
    print(f"\nload average {os.getloadavg()[0]:.2f} at the end")
    return 0


if __name__ == "__main__":
    sys.exit(main())
