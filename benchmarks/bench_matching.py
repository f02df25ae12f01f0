"""Full SeqSLAM matching speed and memory: difference, enhancement and search, Table I parameters.

For each size N (N reference x N query frames) and feature kind (``sad``: 64x32 thumbnails,
2,048 floats, mean absolute difference; ``codes``: 1,024 floats, squared Euclidean), one fresh
process builds the features, warms the compiled kernels up on a small input, then times
``match_sequences(..., keep_matrices=False)`` once and reports the wall time, the CPU time of
all threads (more telling than wall time on a shared machine) and the process's peak resident
memory (``ru_maxrss``; ``before`` is the peak after the features were built, so
``peak - before`` is what matching added).

Baselines, where they finish in reasonable time:

- ``loop``: the plain-Python reference of the tests (``tests/matching/seqslam_loops.py``), at a
  tiny size (``--loop-n``);
- ``numpy``: a direct NumPy implementation (per-query difference rows, sliding-window
  enhancement, per-velocity shifted sums), up to ``--numpy-max`` frames.

Both must give the same matches as the library; the speed ratio is baseline / library.

    /work/venv/bin/python benchmarks/bench_matching.py [--sizes 1000 3600 10000 20000]
        [--kinds sad codes] [--numpy-max 3600] [--loop-n 100] [--threads 2]

Targets (this 2-core machine): 3,600 x 3,600 SAD under 2 s; 20,000 x 20,000 codes under 60 s and
4 GB peak memory.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
DIMS = {"sad": 2048, "codes": 1024}
METRICS = {"sad": "sad", "codes": "sqeuclidean"}


def make_features(kind: str, n: int, *, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Reference and query features of the same route (query = reference + noise), float32."""
    rng = np.random.default_rng(seed)
    reference = rng.standard_normal((n, DIMS[kind]), dtype=np.float32)
    query = reference + rng.standard_normal((n, DIMS[kind]), dtype=np.float32)
    return reference, query


def cpu_seconds() -> float:
    """User + system CPU time of this process, all threads."""
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


# ------------------------------------------------------------------ NumPy baseline (direct)


def numpy_matching(reference, query, *, metric, ds=10, velocities=(0.8, 0.9, 1.0, 1.1),
                   r_window=10):
    """Direct NumPy SeqSLAM with the library's conventions; returns (match, ratio)."""
    R, Q = len(reference), len(query)
    ref = reference.astype(np.float64)
    D = np.empty((R, Q))
    for q in range(Q):
        diff = ref - query[q]
        D[:, q] = np.abs(diff).mean(axis=1) if metric == "sad" else (diff ** 2).sum(axis=1)
    half = r_window // 2
    total, count = np.zeros_like(D), np.zeros((R, 1))
    for k in range(-half, half + 1):
        lo, hi = max(0, -k), min(R, R - k)
        total[lo:hi] += D[lo + k:hi + k]
        count[lo:hi] += 1
    mean = total / count
    total[:] = 0.0
    for k in range(-half, half + 1):
        lo, hi = max(0, -k), min(R, R - k)
        total[lo:hi] += (D[lo + k:hi + k] - mean[lo:hi]) ** 2
    std = np.sqrt(total / np.maximum(count - 1, 1))
    with np.errstate(invalid="ignore", divide="ignore"):
        Z = np.where(std > 0, (D - mean) / std, np.inf)
    Z -= Z[np.isfinite(Z)].min()
    offsets = [[int(np.floor(round(v * j, 9))) for j in range(ds + 1)] for v in velocities]
    match = np.full(Q, -1)
    ratio = np.full(Q, np.nan)
    for T in range(ds, Q):
        best = np.full(R, np.inf)
        for off in offsets:
            acc = np.full(R, np.inf)
            acc[off[ds]:] = 0.0
            for j in range(ds, -1, -1):
                acc[off[ds]:] += Z[off[ds] - off[j]:R - off[j], T - j]
            best = np.minimum(best, acc)
        s = int(np.argmin(best))
        if not np.isfinite(best[s]):
            continue
        outside = np.concatenate([best[:max(0, s - half)], best[s + half + 1:]])
        second = outside.min() if outside.size else np.inf
        match[T] = s
        ratio[T] = 0.0 if np.isinf(second) else (1.0 if second == 0 else best[s] / second)
    return match, ratio


def loop_matching(reference, query, *, metric):
    sys.path.insert(0, str(HERE.parent / "tests" / "matching"))
    from seqslam_loops import loop_difference, loop_enhance, loop_search

    D = loop_difference(reference, query, metric=metric)
    match, _, ratio = loop_search(loop_enhance(D, r_window=10), ds=10,
                                  velocities=[0.8, 0.9, 1.0, 1.1], r_window=10)
    return match, ratio


# ------------------------------------------------------------------------ one measurement


def measure(kind: str, n: int, implementation: str, threads: int) -> dict:
    import numba

    from cmal_lcd.matching import SeqSLAMParams, match_sequences

    numba.set_num_threads(threads)
    reference, query = make_features(kind, n)
    metric = METRICS[kind]
    warm_ref, warm_query = make_features(kind, 64, seed=1)
    match_sequences(warm_ref, warm_query, metric=metric)  # load/compile the kernels
    before = peak_rss_mb()
    cpu_start = cpu_seconds()
    start = time.perf_counter()
    if implementation == "library":
        result = match_sequences(reference, query, metric=metric, params=SeqSLAMParams())
        match = result.match
    elif implementation == "numpy":
        match, _ = numpy_matching(reference, query, metric=metric)
    else:
        match, _ = loop_matching(reference, query, metric=metric)
    seconds = time.perf_counter() - start
    cpu = cpu_seconds() - cpu_start
    if implementation != "library":
        library = match_sequences(reference, query, metric=metric).match
        agree = float(np.mean(library == match))
    else:
        agree = 1.0
    return {"kind": kind, "n": n, "implementation": implementation, "seconds": seconds,
            "cpu_seconds": cpu,
            "peak_mb": peak_rss_mb(), "before_mb": before, "agree": agree}


def run_one(kind: str, n: int, implementation: str, threads: int) -> dict:
    """Measure in a fresh process, so the peak memory is this run's own."""
    out = subprocess.run([sys.executable, __file__, "--one", kind, str(n), implementation,
                          "--threads", str(threads)], check=True, capture_output=True, text=True,
                         env={**os.environ, "OMP_NUM_THREADS": str(threads),
                              "OPENBLAS_NUM_THREADS": str(threads)})
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[1000, 3600, 10000, 20000])
    parser.add_argument("--kinds", nargs="+", default=["sad", "codes"], choices=list(DIMS))
    parser.add_argument("--numpy-max", type=int, default=3600)
    parser.add_argument("--loop-n", type=int, default=100)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--one", nargs=3, metavar=("KIND", "N", "IMPL"), help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.one:
        kind, n, impl = args.one
        print(json.dumps(measure(kind, int(n), impl, args.threads)))
        return
    print(f"{'kind':>5} {'N':>6} {'implementation':>14} {'seconds':>9} {'cpu s':>8} "
          f"{'peak MB':>8} {'added MB':>8} {'ratio':>8} {'agree':>6}")
    for kind in args.kinds:
        sizes = sorted({*args.sizes, *([args.loop_n] if args.loop_n else [])})
        for n in sizes:
            library = run_one(kind, n, "library", args.threads)
            _print(library, None)
            baseline = "loop" if n == args.loop_n else "numpy" if n <= args.numpy_max else None
            if baseline:
                _print(run_one(kind, n, baseline, args.threads), library["seconds"])


def _print(row: dict, library_seconds: float | None) -> None:
    ratio = f"{row['seconds'] / library_seconds:8.1f}" if library_seconds else f"{'':>8}"
    print(f"{row['kind']:>5} {row['n']:>6} {row['implementation']:>14} {row['seconds']:9.2f} "
          f"{row['cpu_seconds']:8.2f} {row['peak_mb']:8.0f} "
          f"{row['peak_mb'] - row['before_mb']:8.0f} {ratio} "
          f"{row['agree']:6.3f}", flush=True)


if __name__ == "__main__":
    main()
