"""Does comparing codes in float32 (``--float32-codes``, metric ``sqeuclidean_f32``) change results?

Issue 14, item 1: a faster difference may replace the exact one only if AUC-PR and R@100P move
by less than 0.005. This script scores the pipeline's own codes (``data/features/<method>``,
written by ``dvc repro``) on every test pair of the dataset, with the evaluate stage's function
and protocols (the one selected on validation, ``data/protocol/<method>.json``, and the paper's:
raw codes, eq. 14), once with ``sqeuclidean`` (float64 product) and once with
``sqeuclidean_f32``, and prints each metric, the difference and the largest one.

    .venv/bin/python benchmarks/check_codes_float32.py [--root .] [--methods cmal bigan ...]

Nothing is chosen from these numbers: the option stays off by default; the figures are quoted
in ``benchmarks/README.md``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from cmal_lcd.config import load_params
from cmal_lcd.data.codes import load_features
from cmal_lcd.data.store import load_dataset
from cmal_lcd.evaluation.loop_closure import evaluate_drive_pairs
from cmal_lcd.evaluation.protocol import paper_protocol
from cmal_lcd.evaluation.protocol_file import centring_means, load_selected_protocol
from cmal_lcd.matching import SeqSLAMParams
from cmal_lcd.matching.difference import CODE_METRICS

METRICS = ("auc_pr", "recall_at_100p")
TOLERANCE = 0.005


def method_scorer(root: Path, method: str):
    """``score(variant, metric) -> {(route, pair): {metric name: value}}`` of ``method``'s test
    pairs, as the evaluate stage computes them, with the codes compared by ``metric``; the
    config, dataset, codes and protocols are read once."""
    cfg = load_params(root / "params.yaml")
    params = SeqSLAMParams.from_config(cfg.matching)
    d_thresh, pose_tolerance = cfg.matching.d_thresh, cfg.matching.pose_tolerance
    features_dir = root / "data" / "features" / method
    selected = load_selected_protocol(root / "data" / "protocol" / f"{method}.json")
    protocols = {"selected": selected, "paper": paper_protocol(params)}
    dataset = load_dataset(root / "data" / "dataset")
    _, frames = dataset.test()
    codes, info = load_features(features_dir, expected_rows=len(frames))
    if info["metric"] != CODE_METRICS["float64"]:
        raise ValueError(f"{features_dir}: metric {info['metric']!r}, not codes")
    means = centring_means(selected, features_dir, len(dataset.conditions))

    def score(variant: str, metric: str) -> dict:
        results = evaluate_drive_pairs(
            codes, frames, dataset.pairs("test"), metric=metric, params=params,
            d_thresh=d_thresh,
            ground_truth=dataset.meta.get("ground_truth", "poses"),
            pose_tolerance=pose_tolerance, protocol=protocols[variant],
            train_means=means)
        return {(route, pair): evaluation.metrics for route, pair, evaluation in results}

    return score


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--root", type=Path, default=Path("."),
                        help="a checkout after dvc repro (params.yaml, data/)")
    parser.add_argument("--methods", nargs="+",
                        default=["dnn", "dnn_head", "bigan", "cmal", "cmal_untrained"])
    args = parser.parse_args(argv)
    worst = 0.0
    print(f"{'method':<15} {'protocol':<9} {'route':<7} {'pair':<12} {'metric':<15} "
          f"{'float64':>8} {'float32':>8} {'diff':>8}")
    for method in args.methods:
        if not (args.root / "data" / "features" / method).is_dir():
            print(f"{args.root / 'data' / 'features' / method}: no codes (run dvc repro)",
                  file=sys.stderr)
            return 2
        score = method_scorer(args.root, method)
        for variant in ("selected", "paper"):
            exact = score(variant, CODE_METRICS["float64"])
            fast = score(variant, CODE_METRICS["float32"])
            for (route, pair), values in exact.items():
                for name in METRICS:
                    diff = fast[route, pair][name] - values[name]
                    worst = max(worst, abs(diff))
                    print(f"{method:<15} {variant:<9} {route:<7} {pair:<12} {name:<15} "
                          f"{values[name]:8.4f} {fast[route, pair][name]:8.4f} {diff:+8.4f}")
    print(f"largest |difference| of AUC-PR and R@100P: {worst:.4f} "
          f"({'within' if worst < TOLERANCE else 'NOT within'} {TOLERANCE})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
