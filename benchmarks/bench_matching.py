"""Full SeqSLAM matching speed and memory: difference, enhancement and search, Table I parameters.

For each size N (N reference x N query frames) and feature kind (``sad``: 64x32 thumbnails,
2,048 floats, mean absolute difference; ``sad_u8``: the same thumbnails quantised to bytes,
``matching.sad.quantise``; ``codes``: 1,024 floats, squared Euclidean; ``codes_f32``: the same
in float32, ``cmal-lcd match --float32-codes``), one fresh
process builds the features, warms the compiled kernels up on a small input, then times
``match_sequences(..., keep_matrices=False)`` once and reports the wall time, the CPU time of
all threads (more telling than wall time on a shared machine) and the process's peak resident
memory (``ru_maxrss``; ``before`` is the peak after the features were built, so
``peak - before`` is what matching added).

Baselines (issue 14, item 3: fair ones), run in their own fresh process the same way:

- ``numpy``: the best plain vectorised NumPy SeqSLAM we could write with the library's exact
  conventions (chunked difference: one float64 matrix product per query chunk for squared
  Euclidean, float32 for ``codes_f32``, cache-blocked broadcast mean absolute difference on ``--threads`` threads for SAD;
  enhancement by cumulative sums; shifted sums over the velocities; same score, ratio and
  uniqueness window), up to ``--numpy-max`` frames and at ``--loop-n``;
- ``loop``: the plain-Python reference of the tests (``tests/matching/seqslam_loops.py``), at a
  tiny size (``--loop-n``) only.

Each baseline must give the same matches as the library (``agree``: fraction of equal
``match``; ``d ratio``: largest absolute difference of the uniqueness ratios, scored queries;
``tests/matching/test_bench_baseline.py`` checks the NumPy baseline on small inputs). ``x lib``
is baseline wall time / library wall time (and the same for CPU time): how many times faster
the library is.

    .venv/bin/python benchmarks/bench_matching.py [--sizes 1000 3600 10000 20000]
        [--kinds sad sad_u8 codes codes_f32] [--numpy-max 3600] [--loop-n 100] [--threads 2]

The baselines of ``sad_u8`` get the same quantised values as floats, and plain SAD.

Targets (issue 14, this 2-core machine, unloaded): 3,600 x 3,600 SAD at most 0.5 s wall;
20,000 x 20,000 codes at most 25 s and under 2 GB peak memory. Figures: ``benchmarks/README.md``.
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
DIMS = {"sad": 2048, "sad_u8": 2048, "codes": 1024, "codes_f32": 1024}
METRICS = {"sad": "sad", "sad_u8": "sad_u8", "codes": "sqeuclidean",
           "codes_f32": "sqeuclidean_f32"}


def make_features(kind: str, n: int, *, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Reference and query features of the same route (query = reference + noise), float32."""
    rng = np.random.default_rng(seed)
    reference = rng.standard_normal((n, DIMS[kind]), dtype=np.float32)
    query = reference + rng.standard_normal((n, DIMS[kind]), dtype=np.float32)
    return reference, query


def baseline_inputs(kind: str, reference: np.ndarray, query: np.ndarray):
    """``(reference, query, metric)`` a baseline compares for ``kind``.

    ``sad_u8`` (the library quantises to bytes ``128 + round(16 z)``): the baselines get the same
    quantised values as floats, ``clip(round(16 z), -128, 127) / 16``, and plain SAD.
    """
    if kind != "sad_u8":
        return reference, query, METRICS[kind]
    def quantised(x):
        return (np.clip(np.rint(x * 16), -128, 127) / 16).astype(np.float32)
    return quantised(reference), quantised(query), "sad"


def cpu_seconds() -> float:
    """User + system CPU time of this process, all threads."""
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


# ------------------------------------------------------------- NumPy baseline (vectorised)
#
# The best plain vectorised NumPy SeqSLAM we could write, with the library's exact conventions
# (``cmal_lcd.matching.seqslam`` module docs), streamed over chunks of queries like the library:
#
# - difference, query-major ``(Qc, R)`` float32: squared Euclidean as one float64 matrix product
#   per chunk (``|a|^2 + |b|^2 - 2 a.b``, clamped at 0, stored as float32: the library's
#   formula); SAD as a mean absolute difference over cache-sized ``(4, 64, F)`` broadcast blocks
#   (subtract, abs, sum), split across ``threads`` Python threads (NumPy releases the GIL);
# - enhancement (eq. 14): window sums from cumulative sums of the centred float64 rows (sample
#   std, ``ddof=1``, clipped windows), constant windows (``+inf``) found exactly from a
#   cumulative count of changes between neighbours;
# - search (eqs. 15-16): per velocity, ``ds + 1`` shifted slices added in ascending time over
#   a block of 16 queries x every end row (float64, the library's order), minimum over
#   velocities, first argmin, best outside the uniqueness window; the search runs on unshifted
#   z-scores and the scores are shifted by ``(ds + 1) min(z)`` at the end, as in the library;
# - single-frame matches on the raw difference (the library computes them too).

#: queries x reference rows per SAD broadcast block (4 x 64 x 2,048 x 4 B = 2 MB, in L2)
NUMPY_SAD_BLOCK = (4, 64)
#: queries per search block: the (16, R) float64 accumulators stay in cache
NUMPY_SEARCH_BLOCK = 16


def _numpy_sad_rows(reference32: np.ndarray, query: np.ndarray, out: np.ndarray,
                    threads: int) -> None:
    """``out[q, r] = mean_k |query[q, k] - reference[r, k]|`` (float32), query-major."""
    qc, rb = NUMPY_SAD_BLOCK
    R, F = reference32.shape
    query = np.ascontiguousarray(query, dtype=np.float32)
    scale = np.float32(1.0 / F)

    def work(q0: int, q1: int) -> None:
        tmp = np.empty((qc, rb, F), dtype=np.float32)
        for i in range(q0, q1, qc):
            i1 = min(q1, i + qc)
            for j in range(0, R, rb):
                j1 = min(R, j + rb)
                t = tmp[:i1 - i, :j1 - j]
                np.subtract(query[i:i1, None, :], reference32[None, j:j1], out=t)
                np.abs(t, out=t)
                np.add.reduce(t, axis=2, out=out[i:i1, j:j1])
        out[q0:q1] *= scale

    n = len(query)
    if threads <= 1 or n < 2 * qc:
        work(0, n)
        return
    from concurrent.futures import ThreadPoolExecutor

    step = -(-n // threads)
    step += -step % qc
    with ThreadPoolExecutor(threads) as pool:
        list(pool.map(lambda q0: work(q0, min(n, q0 + step)), range(0, n, step)))


def _numpy_window_sums(prefix: np.ndarray, lo: np.ndarray, hi: np.ndarray, half: int,
                       inclusive: bool) -> np.ndarray:
    """``prefix[:, hi + e] - prefix[:, lo]`` (``e = 1`` if ``inclusive``) for every row ``i``.

    Full windows (``lo = i - half``, ``hi = i + half``) by two slices; the clipped ones at both
    ends by indexing.
    """
    n = prefix.shape[0]
    R = lo.size
    e = 1 if inclusive else 0
    out = np.empty((n, R), dtype=prefix.dtype)
    if R > 2 * half:
        np.subtract(prefix[:, 2 * half + e:R + e], prefix[:, :R - 2 * half],
                    out=out[:, half:R - half])
        edges = np.r_[0:half, R - half:R]
    else:
        edges = np.arange(R)
    if edges.size:
        out[:, edges] = prefix[:, hi[edges] + e] - prefix[:, lo[edges]]
    return out


def numpy_enhance_rows(rows: np.ndarray, half: int) -> np.ndarray:
    """Eq. 14 of query-major float32 ``rows (n, R)``: float64 unshifted z, ``+inf`` if constant."""
    n, R = rows.shape
    i = np.arange(R)
    lo = np.maximum(0, i - half)
    hi = np.minimum(R - 1, i + half)
    count = (hi - lo + 1).astype(np.float64)
    x = rows.astype(np.float64)
    x -= x.mean(axis=1, keepdims=True)  # centred: small prefix sums, little cancellation
    prefix = np.zeros((n, R + 1))
    np.cumsum(x, axis=1, out=prefix[:, 1:])
    s1 = _numpy_window_sums(prefix, lo, hi, half, inclusive=True)
    np.cumsum(x * x, axis=1, out=prefix[:, 1:])
    s2 = _numpy_window_sums(prefix, lo, hi, half, inclusive=True)
    del prefix
    mean = s1 / count
    s1 *= mean
    var = s2
    var -= s1  # sum of squared deviations
    var /= np.maximum(count - 1, 1)
    # exact constant-window test: no change between neighbours inside the window
    changes = np.zeros((n, R), dtype=np.int32)
    np.cumsum(rows[:, 1:] != rows[:, :-1], axis=1, out=changes[:, 1:])
    constant = _numpy_window_sums(changes, lo, hi, half, inclusive=False) == 0
    constant |= (count < 2)[None, :]
    constant |= var <= 0.0
    x -= mean
    with np.errstate(invalid="ignore", divide="ignore"):
        np.sqrt(var, out=var)
        x /= var
    x[constant] = np.inf
    return x


def _numpy_best_second(values: np.ndarray, half: int):
    """Per row: first argmin (``-1`` if all ``+inf``), its value, best outside ``+-half``."""
    n, R = values.shape
    index = np.argmin(values, axis=1)
    rows = np.arange(n)
    best = values[rows, index].astype(np.float64)
    masked = values.copy()
    cols = np.clip(index[:, None] + np.arange(-half, half + 1)[None, :], 0, R - 1)
    masked[rows[:, None], cols] = np.inf
    second = masked.min(axis=1).astype(np.float64)
    index = np.where(np.isinf(best), -1, index)
    return index, best, second


def numpy_search_rows(rows: np.ndarray, first: int, offsets: np.ndarray, half: int):
    """Look-back search for local queries ``first..n-1`` of query-major ``rows (n, R)``."""
    n, R = rows.shape
    ds = offsets.shape[1] - 1
    match = np.empty(n - first, dtype=np.int64)
    best = np.empty(n - first)
    second = np.empty(n - first)
    for a in range(first, n, NUMPY_SEARCH_BLOCK):
        b = min(n, a + NUMPY_SEARCH_BLOCK)
        per_row = np.full((b - a, R), np.inf)
        for off in offsets:
            o_max = int(off[ds])
            if o_max >= R:
                continue
            acc = rows[a - ds:b - ds, :R - o_max].astype(np.float64)  # j = ds: o = o_max
            for j in range(ds - 1, -1, -1):  # ascending time, as eq. 16 and the library
                o = int(off[j])
                acc += rows[a - j:b - j, o_max - o:R - o]
            np.minimum(per_row[:, o_max:], acc, out=per_row[:, o_max:])
        m, bst, sec = _numpy_best_second(per_row, half)
        match[a - first:b - first], best[a - first:b - first] = m, bst
        second[a - first:b - first] = sec
    return match, best, second


def _numpy_scores_and_ratios(best, second, match, shift):
    scored = match >= 0
    score = np.full(match.shape, np.nan)
    ratio = np.full(match.shape, np.nan)
    b = np.maximum(best[scored] - shift, 0.0)
    s = np.maximum(second[scored] - shift, 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.where(np.isinf(s), 0.0, np.where(s == 0.0, 1.0, b / np.where(s == 0.0, 1.0, s)))
    score[scored] = b
    ratio[scored] = r
    return score, ratio


def numpy_matching(reference, query, *, metric, ds=10, velocities=(0.8, 0.9, 1.0, 1.1),
                   r_window=10, enhance=True, chunk=512, threads=1) -> dict:
    """Vectorised NumPy SeqSLAM with the library's conventions (see the section comment).

    Returns a dict of ``(Q,)`` arrays: ``match``, ``score``, ``ratio``, ``single_frame_match``,
    ``single_frame_ratio``, as :class:`cmal_lcd.matching.MatchResult`.
    """
    reference = np.asarray(reference)
    query = np.asarray(query)
    R, Q = len(reference), len(query)
    half_enh = r_window // 2 if enhance else 0
    half = r_window // 2
    offsets = np.array([[int(np.floor(round(float(v) * j, 9))) for j in range(ds + 1)]
                        for v in velocities], dtype=np.int64)
    if metric == "sad":
        ref32 = np.ascontiguousarray(reference, dtype=np.float32)
    else:
        dtype = np.float32 if metric == "sqeuclidean_f32" else np.float64
        ref_codes = np.ascontiguousarray(reference, dtype=dtype)
        norms = np.einsum("ij,ij->i", ref_codes, ref_codes)
    match = np.full(Q, -1, dtype=np.int64)
    best = np.full(Q, np.nan)
    second = np.full(Q, np.nan)
    sf = [np.empty(Q, dtype=np.int64), np.empty(Q), np.empty(Q)]
    history = np.empty((0, R), dtype=np.float64 if half_enh else np.float32)
    minimum = np.inf
    for c0 in range(0, Q, chunk):
        c1 = min(Q, c0 + chunk)
        d = np.empty((c1 - c0, R), dtype=np.float32)
        if metric == "sad":
            _numpy_sad_rows(ref32, query[c0:c1], d, threads)
        else:
            q = np.ascontiguousarray(query[c0:c1], dtype=ref_codes.dtype)
            prod = q @ ref_codes.T
            prod *= -2.0
            prod += np.einsum("ij,ij->i", q, q)[:, None]
            prod += norms[None, :]
            np.maximum(prod, 0.0, out=prod)
            d[:] = prod
        for k, a in enumerate(_numpy_best_second(d, half)):
            sf[k][c0:c1] = a
        if half_enh:
            z = numpy_enhance_rows(d, half_enh)
            finite = z[np.isfinite(z)]
            if finite.size:
                minimum = min(minimum, float(finite.min()))
        else:
            z = d
        rows = np.concatenate([history, z])
        start = c0 - len(history)
        first = max(ds, c0) - start
        if first < len(rows):
            m, b, s = numpy_search_rows(rows, first, offsets, half)
            match[start + first:c1], best[start + first:c1], second[start + first:c1] = m, b, s
        history = rows[len(rows) - min(ds, len(rows)):]
    shift = minimum if (half_enh and np.isfinite(minimum)) else 0.0
    score, ratio = _numpy_scores_and_ratios(best, second, match, (ds + 1) * shift)
    _, sf_ratio = _numpy_scores_and_ratios(sf[1], sf[2], sf[0], 0.0)
    return {"match": match, "score": score, "ratio": ratio, "single_frame_match": sf[0],
            "single_frame_ratio": sf_ratio}


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
    if implementation != "library":
        library_reference, library_query = reference, query
        reference, query, metric = baseline_inputs(kind, reference, query)
        warm_ref, warm_query, _ = baseline_inputs(kind, warm_ref, warm_query)
    if implementation == "numpy":
        numpy_matching(warm_ref, warm_query, metric=metric, threads=threads)
    before = peak_rss_mb()
    cpu_start = cpu_seconds()
    start = time.perf_counter()
    if implementation == "library":
        result = match_sequences(reference, query, metric=metric, params=SeqSLAMParams.defaults())
        match, ratio = result.match, result.ratio
    elif implementation == "numpy":
        out = numpy_matching(reference, query, metric=metric, threads=threads)
        match, ratio = out["match"], out["ratio"]
    else:
        match, ratio = loop_matching(reference, query, metric=metric)
    seconds = time.perf_counter() - start
    cpu = cpu_seconds() - cpu_start
    peak = peak_rss_mb()
    agree, d_ratio = 1.0, 0.0
    if implementation != "library":
        library = match_sequences(library_reference, library_query, metric=METRICS[kind])
        agree = float(np.mean(library.match == match))
        scored = library.match >= 0
        d_ratio = float(np.max(np.abs(library.ratio[scored] - ratio[scored]), initial=0.0))
    return {"kind": kind, "n": n, "implementation": implementation, "seconds": seconds,
            "cpu_seconds": cpu, "peak_mb": peak, "before_mb": before, "agree": agree,
            "d_ratio": d_ratio}


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
    parser.add_argument("--kinds", nargs="+", default=["sad", "sad_u8", "codes"], choices=list(DIMS))
    parser.add_argument("--numpy-max", type=int, default=3600)
    parser.add_argument("--loop-n", type=int, default=100)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--one", nargs=3, metavar=("KIND", "N", "IMPL"), help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.one:
        kind, n, impl = args.one
        print(json.dumps(measure(kind, int(n), impl, args.threads)))
        return
    print(f"machine: {os.cpu_count()} CPUs, {_cpu_model()}; os.getloadavg() at start: "
          f"{' '.join(f'{x:.1f}' for x in os.getloadavg())}; threads {args.threads}")
    print(f"{'kind':>6} {'N':>6} {'implementation':>14} {'seconds':>9} {'cpu s':>8} "
          f"{'peak MB':>8} {'added MB':>8} {'x lib':>7} {'x lib cpu':>9} {'agree':>6} "
          f"{'d ratio':>8}")
    for kind in args.kinds:
        sizes = sorted({*args.sizes, *([args.loop_n] if args.loop_n else [])})
        for n in sizes:
            library = run_one(kind, n, "library", args.threads)
            _print(library, None)
            baselines = (["numpy"] if n <= args.numpy_max or n == args.loop_n else []) \
                + (["loop"] if n == args.loop_n else [])
            for baseline in baselines:
                _print(run_one(kind, n, baseline, args.threads), library)


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return "unknown CPU"


def _print(row: dict, library: dict | None) -> None:
    if library:
        ratio = f"{row['seconds'] / library['seconds']:7.1f}"
        ratio_cpu = f"{row['cpu_seconds'] / max(library['cpu_seconds'], 1e-9):9.1f}"
    else:
        ratio, ratio_cpu = f"{'':>7}", f"{'':>9}"
    print(f"{row['kind']:>6} {row['n']:>6} {row['implementation']:>14} {row['seconds']:9.2f} "
          f"{row['cpu_seconds']:8.2f} {row['peak_mb']:8.0f} "
          f"{row['peak_mb'] - row['before_mb']:8.0f} {ratio} {ratio_cpu} "
          f"{row['agree']:6.3f} {row['d_ratio']:8.1e}", flush=True)


if __name__ == "__main__":
    main()
