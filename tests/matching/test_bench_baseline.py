"""The benchmark's vectorised NumPy SeqSLAM baseline agrees with the library (issue 14, item 3).

``benchmarks/bench_matching.py`` reports speed ratios against ``numpy_matching``; a ratio is
only fair if the baseline does the same work with the same conventions, so it must give the
library's ``match`` and single-frame match exactly and its ratios and scores to rounding (SAD:
float32 sums in another order, about 1e-7; squared Euclidean: the same float64 products;
in float32 (``codes_f32``), products blocked otherwise by BLAS, about 1e-7).
"""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from cmal_lcd.matching import SeqSLAMParams, match_sequences

BENCH = Path(__file__).resolve().parents[2] / "benchmarks" / "bench_matching.py"


def _load_bench():
    spec = importlib.util.spec_from_file_location("bench_matching", BENCH)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


bench = _load_bench()


def _features(kind, n_ref, n_query, seed, tunnel=False):
    reference, query = bench.make_features(kind, max(n_ref, n_query), seed=seed)
    reference, query = reference[:n_ref].copy(), query[:n_query].copy()
    if tunnel:  # identical frames: constant enhancement windows (+inf cells, excluded)
        reference[20:35] = reference[20]
    return reference, query


def _check(reference, query, *, kind, enhance, chunk, threads, sad_tol=1e-6):
    metric = bench.METRICS[kind]
    lib = match_sequences(reference, query, metric=metric, params=SeqSLAMParams.defaults(enhance=enhance))
    out = bench.numpy_matching(reference, query, metric=metric, enhance=enhance, chunk=chunk,
                               threads=threads)
    np.testing.assert_array_equal(out["match"], lib.match)
    np.testing.assert_array_equal(out["single_frame_match"], lib.single_frame_match)
    for key in ("ratio", "score", "single_frame_ratio"):
        mine, theirs = out[key], getattr(lib, key)
        np.testing.assert_array_equal(np.isnan(mine), np.isnan(theirs))
    tol = 1e-12 if kind == "codes" else sad_tol  # float64 products agree to the last bits
    np.testing.assert_allclose(out["ratio"], lib.ratio, rtol=0, atol=tol)
    np.testing.assert_allclose(out["single_frame_ratio"], lib.single_frame_ratio, rtol=0,
                               atol=tol)
    np.testing.assert_allclose(out["score"], lib.score, rtol=10 * tol, atol=10 * tol)
    return lib


@pytest.mark.parametrize("kind", ["sad", "codes", "codes_f32"])
@pytest.mark.parametrize("enhance", [True, False])
@pytest.mark.parametrize("shape", [(90, 70, 16), (140, 120, 37)])
def test_numpy_baseline_agrees_with_library(kind, enhance, shape):
    n_ref, n_query, chunk = shape
    reference, query = _features(kind, n_ref, n_query, seed=n_ref)
    lib = _check(reference, query, kind=kind, enhance=enhance, chunk=chunk, threads=2)
    assert lib.n_scored == n_query - 10


@pytest.mark.parametrize("kind", ["sad", "codes", "codes_f32"])
def test_numpy_baseline_constant_windows(kind):
    reference, query = _features(kind, 80, 60, seed=7, tunnel=True)
    # windows of nearly constant values next to the tunnel have a small std, which magnifies
    # the float32 rounding of SAD (the library's own error against float64): ratios to 1e-5
    lib = _check(reference, query, kind=kind, enhance=True, chunk=25, threads=1, sad_tol=1e-5)
    assert lib.n_scored > 0


def test_numpy_baseline_too_few_reference_rows():
    # R = 8 < the longest trajectory offset (11): no valid trajectory, nothing scored
    reference, query = _features("sad", 8, 30, seed=3)
    lib = _check(reference, query, kind="sad", enhance=True, chunk=9, threads=2)
    assert lib.n_scored == 0
