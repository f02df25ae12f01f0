"""Does quantising the SAD thumbnails (``matching.sad.quantise``, metric ``sad_u8``) change results?

Issue 14, item 1: a quantised SAD may replace the float one only if, on the Nordland pairs in
``../shared``, AUC-PR and R@100P move by less than 0.005. This script matches the 1,800 Nordland
places both ways (summer reference / winter query, and winter / summer) with Table I's SeqSLAM,
with the paper's enhancement (eq. 14) and without it, once with ``sad`` and once with
``sad_u8``, and prints each metric, the difference, and the time of the difference matrix.

    .venv/bin/python benchmarks/check_sad_quantised.py [--nordland ../shared/data/nordland_summer_winter]

Nothing is chosen from these numbers: the option stays off by default (``conf/matching``);
the figures are quoted in ``benchmarks/README.md``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from cmal_lcd.data.frames import read_frame_folder
from cmal_lcd.evaluation import ground_truth_from_correspondence
from cmal_lcd.evaluation.loop_closure import evaluate_pair
from cmal_lcd.matching import SeqSLAMParams, difference_matrix, sad_thumbnails

METRICS = ("auc_pr", "recall_at_100p", "recall_at_1")
TOLERANCE = 0.005


def compare(reference: np.ndarray, query: np.ndarray, params: SeqSLAMParams) -> dict:
    """``{metric name: (sad value, sad_u8 value)}`` for one direction and one setting."""
    truth = ground_truth_from_correspondence(len(reference), len(query))
    values = {}
    for metric in ("sad", "sad_u8"):
        result = evaluate_pair(reference, query, truth, metric=metric, params=params,
                               d_thresh=20)
        values[metric] = result.metrics
    return {name: (values["sad"][name], values["sad_u8"][name]) for name in METRICS}


def best_time(reference: np.ndarray, query: np.ndarray, metric: str, repeat: int = 3) -> float:
    """Best wall time of the full difference matrix, seconds (after a warm-up call)."""
    difference_matrix(reference[:8], query[:8], metric=metric)
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        difference_matrix(reference, query, metric=metric)
        times.append(time.perf_counter() - start)
    return min(times)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--nordland", type=Path,
                        default=Path(__file__).resolve().parents[2] / "shared" / "data"
                        / "nordland_summer_winter")
    args = parser.parse_args(argv)
    if not (args.nordland / "summer").is_dir():
        print(f"{args.nordland}: no summer/ and winter/ frame folders", file=sys.stderr)
        return 2
    summer = sad_thumbnails(read_frame_folder(args.nordland / "summer").images)
    winter = sad_thumbnails(read_frame_folder(args.nordland / "winter").images)
    print(f"Nordland: {len(summer)} places, thumbnails {summer.shape[1]} values; "
          f"z-scores in [{min(summer.min(), winter.min()):.3f}, "
          f"{max(summer.max(), winter.max()):.3f}]")
    worst = 0.0
    print(f"{'direction':<16} {'enhance':<8} {'metric':<15} {'sad':>8} {'sad_u8':>8} {'diff':>8}")
    for name, (reference, query) in {"summer/winter": (summer, winter),
                                     "winter/summer": (winter, summer)}.items():
        for enhance in (True, False):
            rows = compare(reference, query, SeqSLAMParams.defaults(enhance=enhance))
            for metric, (exact, quantised) in rows.items():
                diff = quantised - exact
                if metric != "recall_at_1":
                    worst = max(worst, abs(diff))
                print(f"{name:<16} {str(enhance):<8} {metric:<15} {exact:8.4f} {quantised:8.4f} "
                      f"{diff:+8.4f}")
    print(f"largest |difference| of AUC-PR and R@100P: {worst:.4f} "
          f"({'within' if worst < TOLERANCE else 'NOT within'} {TOLERANCE})")
    for metric in ("sad", "sad_u8"):
        print(f"difference matrix {len(summer)} x {len(winter)}, {metric}: "
              f"{best_time(summer, winter, metric):.3f} s (best of 3)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
