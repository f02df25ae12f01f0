"""Benchmark: wall time of the report stage on a paper-sized run of synthetic inputs.

Writes evaluation, feature and model files in the formats of docs/architecture.md (random
values, no training) for ``--routes`` routes x 3 weather pairs x 5 methods, with
``--frames`` x ``--frames`` difference matrices and PR curves of ``--frames`` points, then times
:func:`cmal_lcd.stages.report.main` and prints the time and what it wrote::

    /work/venv/bin/python benchmarks/bench_report.py [--routes 2] [--frames 300] [--repeats 2]
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd
from omegaconf import OmegaConf

from cmal_lcd.stages import report

METHODS = ("sad", "dnn", "bigan", "cmal", "cmal_untrained")
PAIRS = ("foggy-rainy", "foggy-sunny", "rainy-sunny")
KEYS = ("auc_pr", "auc_roc", "recall_at_100p", "recall_at_1", "single_frame_recall_at_1")


def write_inputs(root: Path, *, routes: int, frames: int, seed: int = 0) -> dict[str, Path]:
    rng = np.random.default_rng(seed)
    dirs = {"evaluation": root / "data/evaluation", "features": root / "data/features",
            "models": root / "models", "dataset": root / "data/dataset"}
    for method in METHODS:
        metrics: dict = {}
        for r in range(routes):
            route = f"route{r + 1}"
            for pair in PAIRS:
                metrics.setdefault(route, {})[pair] = {
                    v: {k: float(rng.uniform()) for k in KEYS} for v in ("enhanced", "plain")}
                recall = np.sort(rng.uniform(size=frames))
                pr = dirs["evaluation"] / method / "pr" / route / f"{pair}.csv"
                pr.parent.mkdir(parents=True, exist_ok=True)
                curve = pd.DataFrame({"recall": recall, "precision": 1 - 0.5 * recall,
                                      "threshold": np.sort(rng.uniform(size=frames))})
                curve.to_csv(pr, index=False)
                D = rng.uniform(size=(frames, frames)).astype(np.float32)
                npz = dirs["evaluation"] / method / "matrices" / route / f"{pair}.npz"
                npz.parent.mkdir(parents=True, exist_ok=True)
                np.savez(npz, D=D, D_hat=D - D.mean(), match=np.arange(frames),
                         truth=np.arange(frames))
        (dirs["evaluation"] / method / "metrics.json").write_text(json.dumps(metrics))
        (dirs["features"] / method).mkdir(parents=True, exist_ok=True)
        (dirs["features"] / method / "info.json").write_text(json.dumps(
            {"label": method.upper(), "metric": "sqeuclidean", "dim": 1024, "dtype": "float32",
             "bytes_per_frame": 4096, "weights": "random",
             "timing": {"device": "cpu", "batch1_ms": 1.0, "batched_ms": 0.5,
                        "batch_size": 32, "repeats": 20}}))
    for name in ("cmal", "bigan"):
        (dirs["models"] / name).mkdir(parents=True, exist_ok=True)
        pd.DataFrame({"iteration": np.arange(0, 5000, 50), "D/loss": rng.uniform(size=100),
                      "G/adv": rng.uniform(size=100)}).to_csv(
            dirs["models"] / name / "train_log.csv", index=False)
    return dirs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--routes", type=int, default=2)
    parser.add_argument("--frames", type=int, default=300)
    parser.add_argument("--repeats", type=int, default=2)
    args = parser.parse_args()
    cfg = OmegaConf.create({"seed": 0, "methods": list(METHODS), "model_names": ["cmal", "bigan"],
                            "models": {"cmal": {"heldout_fraction": 0.05}},
                            "runtime": {"threads": 1},
                            "matching": {"ds": 10, "v_min": 0.8, "v_max": 1.1, "v_step": 0.1,
                                         "r_window": 10, "enhance": True, "score": "ratio",
                                         "d_thresh": 20}})
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        dirs = write_inputs(root, routes=args.routes, frames=args.frames)
        times = []
        for _ in range(args.repeats):
            start = time.perf_counter()
            report.main(cfg, evaluation_dir=dirs["evaluation"], features_dir=dirs["features"],
                        models_dir=dirs["models"], dataset_dir=dirs["dataset"],
                        out_dir=root / "reports", repo_dir=root)
            times.append(time.perf_counter() - start)
        files = [p for p in (root / "reports").rglob("*") if p.is_file()]
        size = sum(p.stat().st_size for p in files)
        print(f"report stage: {args.routes} routes x {len(PAIRS)} pairs x {len(METHODS)} methods, "
              f"{args.frames}x{args.frames} matrices: median {statistics.median(times):.1f} s "
              f"over {args.repeats} runs (min {min(times):.1f} s); {len(files)} files, "
              f"{size / 1e6:.1f} MB")


if __name__ == "__main__":
    main()
