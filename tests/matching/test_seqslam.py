"""SeqSLAM enhancement and look-back sequence search against the plain-loop reference.

The vectorised, chunked, streamed implementation must equal ``seqslam_loops`` (written from the
definitions with Python loops) to 1e-9 on every query.
"""

import math

import numba
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from seqslam_loops import loop_enhance, loop_search, loop_single_frame, loop_velocities

from cmal_lcd.matching import (
    SeqSLAMParams,
    difference_matrix,
    enhance_contrast,
    match_sequences,
    sequence_search,
    single_frame_matches,
)

TOL = dict(rtol=1e-9, atol=1e-9)


def route_features(n_ref, n_query, *, dim=12, noise=0.3, shift=0, seed=0):
    """Reference frames along a smooth route; the query revisits it from ``shift`` on, noisily."""
    rng = np.random.default_rng(seed)
    world = np.cumsum(rng.normal(size=(n_ref + n_query + shift, dim)), axis=0)
    reference = world[:n_ref]
    query = world[shift:shift + n_query] + noise * rng.normal(size=(n_query, dim))
    return reference.astype(np.float32), query.astype(np.float32)


def assert_same_matches(result, expected):
    match, score, ratio = expected
    np.testing.assert_array_equal(result.match, match)
    np.testing.assert_allclose(result.score, score, **TOL)
    np.testing.assert_allclose(result.ratio, ratio, **TOL)


# ----------------------------------------------------------------------------- enhancement


def test_enhancement_equals_the_loop():
    D = np.random.default_rng(0).random((30, 9)).astype(np.float32)
    np.testing.assert_allclose(enhance_contrast(D, r_window=10),
                               loop_enhance(D, r_window=10).astype(np.float32), rtol=1e-6,
                               atol=1e-6)


def test_enhanced_values_are_non_negative_with_minimum_zero():
    D_hat = enhance_contrast(np.random.default_rng(1).random((25, 6)), r_window=6)
    assert D_hat.dtype == np.float32 and D_hat.shape == (25, 6)
    assert D_hat.min() == 0.0 and np.isfinite(D_hat).all()


def test_constant_windows_are_excluded_as_inf_never_nan():
    D = np.random.default_rng(2).random((40, 5)).astype(np.float32)
    D[10:30, 2] = 0.5  # identical tunnel frames: a constant stretch in query column 2
    D_hat = enhance_contrast(D, r_window=10)
    assert not np.isnan(D_hat).any()
    assert np.isinf(D_hat[15:25, 2]).all()  # windows fully inside the stretch
    assert np.isfinite(D_hat[:5, 2]).all() and np.isfinite(np.delete(D_hat, 2, axis=1)).all()
    np.testing.assert_array_equal(np.isinf(D_hat), np.isinf(loop_enhance(D, r_window=10)))


def test_all_constant_matrix_gives_all_inf_and_no_match():
    D = np.ones((20, 15), dtype=np.float32)
    assert np.isinf(enhance_contrast(D)).all()
    result = match_sequences(np.zeros((20, 3)), np.zeros((15, 3)), metric="sad")
    assert (result.match == -1).all() and np.isnan(result.ratio).all()


def test_r_window_zero_means_no_enhancement():
    D = np.random.default_rng(3).random((8, 4)).astype(np.float32)
    np.testing.assert_array_equal(enhance_contrast(D, r_window=0), D)
    with pytest.raises(ValueError, match="r_window"):
        enhance_contrast(D, r_window=1)


# ---------------------------------------------------------------------------------- search


@settings(max_examples=40, deadline=None)
@given(R=st.integers(1, 25), Q=st.integers(1, 16), ds=st.integers(1, 5),
       v=st.sampled_from([(0.8, 1.1, 0.1), (1.0, 1.0, 0.1), (0.5, 2.0, 0.5), (0.3, 0.9, 0.3)]),
       r_window=st.sampled_from([0, 2, 4, 10]), n_inf=st.integers(0, 12),
       dtype=st.sampled_from([np.float32, np.float64]), seed=st.integers(0, 2**16))
def test_search_equals_the_loop_on_random_matrices(R, Q, ds, v, r_window, n_inf, dtype, seed):
    rng = np.random.default_rng(seed)
    D_hat = rng.random((R, Q)).astype(dtype)
    D_hat.flat[rng.choice(R * Q, size=min(n_inf, R * Q), replace=False)] = np.inf
    result = sequence_search(D_hat, ds=ds, v_min=v[0], v_max=v[1], v_step=v[2],
                             r_window=r_window)
    assert_same_matches(result, loop_search(D_hat, ds=ds, velocities=loop_velocities(*v),
                                            r_window=r_window))


def test_queries_without_ds_history_are_not_scored():
    result = sequence_search(np.random.default_rng(4).random((30, 12)), ds=4)
    assert (result.match[:4] == -1).all() and np.isnan(result.score[:4]).all()
    assert np.isnan(result.ratio[:4]).all()
    assert (result.match[4:] >= 0).all() and np.isfinite(result.ratio[4:]).all()


def test_trajectory_looks_back_and_ends_at_the_query():
    # a zero-cost diagonal of velocity 1 ending at row 20 for query 10: cells (10+k, k)
    D_hat = np.ones((40, 11))
    for k in range(11):
        D_hat[10 + k, k] = 0.0
    result = sequence_search(D_hat, ds=10, v_min=1.0, v_max=1.0, v_step=0.1, r_window=4)
    assert result.match[10] == 20 and result.score[10] == 0.0


def test_velocity_two_route_is_found_with_velocity_two():
    reference, _ = route_features(80, 1)
    query = reference[::2][:40]  # the query moves two reference frames per frame
    params = SeqSLAMParams.defaults(ds=6, v_min=1.0, v_max=2.0, v_step=1.0, r_window=4)
    result = match_sequences(reference, query, metric="sqeuclidean", params=params)
    np.testing.assert_array_equal(result.match[6:], 2 * np.arange(6, 40))


def test_ratio_guards_give_zero_without_competitor_and_one_for_ties():
    lone = sequence_search(np.random.default_rng(5).random((3, 6)), ds=2, r_window=10)
    assert (lone.ratio[2:] == 0.0).all()  # no row outside the window: maximally unique
    flat = sequence_search(np.zeros((12, 6)), ds=2, r_window=2)
    assert (flat.ratio[2:] == 1.0).all()  # 0 / 0: indistinguishable
    # ties go to the lowest row with a valid trajectory: v=0.8 reaches back floor(1.6) = 1 row
    assert (flat.match[2:] == 1).all()


def test_search_rejects_negative_or_nan_values():
    with pytest.raises(ValueError, match="negative"):
        sequence_search(-np.ones((5, 5)), ds=2)
    with pytest.raises(ValueError, match="NaN"):
        sequence_search(np.full((5, 5), np.nan), ds=2)


# ----------------------------------------------------------------------- full, streamed run


@pytest.mark.parametrize("metric", ["sad", "sqeuclidean"])
@pytest.mark.parametrize("params", [SeqSLAMParams.defaults(ds=4, r_window=6),
                                    SeqSLAMParams.defaults(ds=3, r_window=4, enhance=False),
                                    SeqSLAMParams.defaults(ds=5, v_min=0.5, v_max=1.5, v_step=0.5,
                                                  r_window=8, score="sum")])
def test_streamed_matching_equals_the_loop_pipeline(metric, params):
    reference, query = route_features(28, 19, shift=3)
    result = match_sequences(reference, query, metric=metric, params=params, keep_matrices=True,
                             chunk_size=4)
    D_hat = (loop_enhance(result.D, r_window=params.r_window) if params.enhance
             else result.D.astype(np.float64))
    expected = loop_search(D_hat, ds=params.ds, velocities=list(params.velocities()),
                           r_window=params.r_window)
    assert_same_matches(result, expected)
    sf_match, sf_ratio = loop_single_frame(result.D, r_window=params.r_window)
    np.testing.assert_array_equal(result.single_frame_match, sf_match)
    np.testing.assert_allclose(result.single_frame_ratio, sf_ratio, **TOL)
    expected_confidence = expected[2] if params.score == "ratio" else expected[1]
    np.testing.assert_allclose(result.confidence_score, expected_confidence, **TOL)


@pytest.mark.parametrize("chunk_size", [1, 2, 5, 13, None])
def test_results_do_not_depend_on_the_chunk_size(chunk_size):
    reference, query = route_features(40, 31, shift=5)
    whole = match_sequences(reference, query, metric="sad", chunk_size=10_000)
    chunked = match_sequences(reference, query, metric="sad", chunk_size=chunk_size)
    for field in ("match", "score", "ratio", "single_frame_match", "single_frame_ratio"):
        np.testing.assert_array_equal(getattr(chunked, field), getattr(whole, field), field)


def test_streamed_matching_agrees_with_the_public_functions_composed():
    reference, query = route_features(35, 24, shift=2)
    params = SeqSLAMParams.defaults(ds=5)
    result = match_sequences(reference, query, metric="sad", params=params, keep_matrices=True)
    D = difference_matrix(reference, query, metric="sad")
    D_hat = enhance_contrast(D, r_window=params.r_window)
    np.testing.assert_array_equal(result.D, D)
    np.testing.assert_array_equal(result.D_hat, D_hat)
    composed = sequence_search(D_hat, ds=5, r_window=params.r_window)
    np.testing.assert_array_equal(result.match, composed.match)
    # the stream searches unrounded float64 enhanced values; D_hat is stored as float32
    np.testing.assert_allclose(result.score, composed.score, rtol=1e-5, atol=1e-5)
    sf_match, sf_ratio = single_frame_matches(D, r_window=params.r_window)
    np.testing.assert_array_equal(result.single_frame_match, sf_match)
    np.testing.assert_allclose(result.single_frame_ratio, sf_ratio, **TOL)


def test_results_do_not_depend_on_the_number_of_threads():
    reference, query = route_features(60, 40, shift=4)
    before = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        one = match_sequences(reference, query, metric="sad", keep_matrices=True)
        numba.set_num_threads(min(2, numba.config.NUMBA_NUM_THREADS))
        two = match_sequences(reference, query, metric="sad", keep_matrices=True)
    finally:
        numba.set_num_threads(before)
    for field in ("match", "score", "ratio", "D", "D_hat"):
        np.testing.assert_array_equal(getattr(one, field), getattr(two, field), field)


def test_revisited_route_is_matched_at_the_right_places():
    reference, query = route_features(120, 80, shift=25, noise=0.5)
    result = match_sequences(reference, query, metric="sqeuclidean")
    scored = result.match >= 0
    assert scored.sum() == 80 - 10
    error = result.match[scored] - (np.arange(10, 80) + 25)
    assert np.abs(error).max() <= 1 and (error == 0).mean() > 0.9


def test_query_shorter_than_the_look_back_is_entirely_unscored():
    reference, query = route_features(30, 10)
    result = match_sequences(reference, query, metric="sad")
    assert (result.match == -1).all() and result.n_scored == 0
    assert (result.single_frame_match >= 0).all()


def test_matrices_are_only_kept_when_asked():
    reference, query = route_features(20, 15)
    plain = match_sequences(reference, query, metric="sad")
    assert plain.D is None and plain.D_hat is None
    kept = match_sequences(reference, query, metric="sad", keep_matrices=True)
    assert kept.D.shape == kept.D_hat.shape == (20, 15)
    assert kept.D_hat.min() == 0.0


def test_confidence_score_follows_params_score():
    reference, query = route_features(30, 20)
    ratio = match_sequences(reference, query, metric="sad", params=SeqSLAMParams.defaults(ds=3))
    total = match_sequences(reference, query, metric="sad",
                            params=SeqSLAMParams.defaults(ds=3, score="sum"))
    np.testing.assert_array_equal(ratio.confidence_score, ratio.ratio)
    np.testing.assert_array_equal(total.confidence_score, total.score)
    scored = ratio.match >= 0
    assert ((ratio.ratio[scored] >= 0) & (ratio.ratio[scored] <= 1)).all()


@pytest.mark.parametrize("kwargs, name", [({"params": {"ds": 3}}, "params"),
                                          ({"chunk_size": 0}, "chunk_size"),
                                          ({"metric": "l1"}, "metric")])
def test_invalid_arguments_raise_naming_them(kwargs, name):
    reference, query = route_features(10, 10)
    with pytest.raises(ValueError, match=name):
        match_sequences(reference, query, **{"metric": "sad", **kwargs})


def test_no_nan_for_scored_queries_on_tunnel_like_features():
    rng = np.random.default_rng(6)
    reference = rng.normal(size=(60, 16)).astype(np.float32)
    reference[20:40] = 0.0  # a tunnel: identical black frames
    query = reference + 0.1 * rng.normal(size=reference.shape).astype(np.float32)
    query[22:38] = 0.0
    result = match_sequences(reference, query, metric="sad")
    scored = result.match >= 0
    assert np.isfinite(result.score[scored]).all() and np.isfinite(result.ratio[scored]).all()
    assert not math.isnan(float(np.nansum(result.score)))
