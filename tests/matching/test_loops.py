"""Single-traversal SeqSLAM (``cmal_lcd.matching.loops``) against a plain Python loop.

The loop below is written from the module's definitions: the self-difference matrix, the
exclusion zone as a prefix of allowed rows per query, eq. 14 over that prefix only (windows
clipped at the boundary), the global minimum subtracted, then ``seqslam_loops.loop_search``.
"""

import math

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from seqslam_loops import (loop_difference, loop_row_scores, loop_search, loop_single_frame,
                           window_zscore)

from cmal_lcd.matching import SeqSLAMParams, match_sequences
from cmal_lcd.matching.loops import (exclusion_limits, exclusion_mask, match_loops,
                                     travelled_distance)

TOL = dict(rtol=1e-9, atol=1e-9)


def loop_allowed(n, *, frames, metres=None, travelled=None):
    """Allowed rows per query, one pair at a time."""
    out = []
    for q in range(n):
        count = 0
        for r in range(n):
            ok = q - r > frames
            if metres is not None:
                ok = ok and travelled[q] - travelled[r] > metres
            count += ok
        out.append(count)
    return np.array(out, dtype=np.int64)


def loop_prefix_enhance(D, n_allowed, *, r_window):
    """Eq. 14 per column over rows ``0 .. n_allowed[q] - 1``; ``inf`` elsewhere; min shifted."""
    N = D.shape[0]
    half = r_window // 2
    Z = np.full((N, N), math.inf)
    for q in range(N):
        L = int(n_allowed[q])
        for i in range(L):
            Z[i, q] = window_zscore(D[:, q], i, half=half, last=L - 1)
    finite = [z for z in Z.ravel() if math.isfinite(z)]
    if finite:
        Z = np.where(np.isfinite(Z), Z - min(finite), Z)
    return Z


def loop_masked(D, n_allowed):
    D = np.asarray(D, dtype=np.float64).copy()
    for q in range(D.shape[0]):
        D[int(n_allowed[q]):, q] = math.inf
    return D


def loop_has_competitor(D_hat, match, *, ds, velocities, r_window):
    """Whether a valid trajectory ends outside ``match +- r_window//2`` (per query)."""
    R, Q = D_hat.shape
    out = np.zeros(Q, bool)
    for T in range(Q):
        if match[T] < 0:
            continue
        for s in range(R):
            if abs(s - match[T]) <= r_window // 2:
                continue
            for v in velocities:
                rows = [s - math.floor(round(v * (T - t), 9)) for t in range(T - ds, T + 1)]
                if min(rows) >= 0 and all(math.isfinite(D_hat[k, t])
                                          for k, t in zip(rows, range(T - ds, T + 1))):
                    out[T] = True
    return out


def loop_pipeline(features, *, params, n_allowed):
    """``D``, ``D_hat`` and ``(match, score, ratio)``; ratio 1 where no competitor exists."""
    D = loop_masked(loop_difference(features, features, metric="sad"), n_allowed)
    D_hat = (loop_prefix_enhance(D, n_allowed, r_window=params.r_window)
             if params.enhance and params.r_window else D)
    velocities = list(params.velocities())
    match, score, ratio = loop_search(D_hat, ds=params.ds, velocities=velocities,
                                      r_window=params.r_window)
    alone = (match >= 0) & ~loop_has_competitor(D_hat, match, ds=params.ds,
                                                velocities=velocities, r_window=params.r_window)
    return D, D_hat, (match, score, np.where(alone, 1.0, ratio))


def looping_route(n_lap=30, *, laps=2, dim=16, noise=0.2, seed=0):
    """Features of a circuit driven ``laps`` times (the same places each lap, noisily)."""
    rng = np.random.default_rng(seed)
    places = np.cumsum(rng.normal(size=(n_lap, dim)), axis=0)
    return np.concatenate([places + noise * rng.normal(size=places.shape)
                           for _ in range(laps)]).astype(np.float32)


# ----------------------------------------------------------------------------- exclusion zone


@given(n=st.integers(0, 20), frames=st.integers(0, 25), metres=st.one_of(
    st.none(), st.floats(0, 30)), seed=st.integers(0, 2**16))
@settings(max_examples=60, deadline=None)
def test_exclusion_limits_equal_the_pairwise_loop(n, frames, metres, seed):
    steps = np.random.default_rng(seed).integers(0, 4, size=max(n - 1, 0)).astype(float)
    travelled = np.concatenate([[0.0], np.cumsum(steps)])[:n]
    got = exclusion_limits(n, frames=frames, metres=metres, travelled=travelled)
    np.testing.assert_array_equal(got, loop_allowed(n, frames=frames, metres=metres,
                                                    travelled=travelled))


def test_travelled_distance_sums_the_steps():
    xy = np.array([[0, 0], [3, 4], [3, 4], [3, 10]], float)
    np.testing.assert_array_equal(travelled_distance(xy), [0, 5, 5, 11])


def test_exclusion_mask_marks_rows_at_or_beyond_the_limit():
    mask = exclusion_mask(np.array([0, 0, 1]))
    np.testing.assert_array_equal(mask[:, 2], [False, True, True])
    assert mask[:, 0].all()


@pytest.mark.parametrize("kwargs, name", [({"frames": -1}, "frames"),
                                          ({"metres": 5.0}, "travelled"),
                                          ({"metres": -1.0, "travelled": np.zeros(4)}, "metres"),
                                          ({"metres": 1.0, "travelled": np.array([0, 2, 1, 3.])},
                                           "non-decreasing")])
def test_exclusion_limits_reject_bad_arguments_naming_them(kwargs, name):
    with pytest.raises(ValueError, match=name):
        exclusion_limits(4, **kwargs)


# ------------------------------------------------------------------------ against the loop


@given(N=st.integers(1, 14), F=st.sampled_from([4, 8]), ds=st.integers(1, 3),
       v=st.sampled_from([(0.8, 1.1, 0.1), (1.0, 1.0, 0.1), (0.5, 2.0, 0.5)]),
       r_window=st.sampled_from([0, 2, 3, 4]), enhance=st.booleans(),
       frames=st.integers(0, 4), levels=st.integers(1, 6), seed=st.integers(0, 2**16))
@settings(max_examples=80, deadline=None)
# an exact tie that the enhancement's float64 rounding turns into scores 1.1e-16 apart
@example(N=8, F=8, ds=1, v=(0.5, 2.0, 0.5), r_window=2, enhance=True, frames=4, levels=3,
         seed=1533)
# an exact tie of the loop (rows 6 and 8) that the library's order of summation breaks
@example(N=11, F=4, ds=2, v=(0.5, 2.0, 0.5), r_window=2, enhance=True, frames=0, levels=2,
         seed=252)
def test_match_loops_equals_the_loop_on_tiny_sequences(N, F, ds, v, r_window, enhance, frames,
                                                       levels, seed):
    # small integers: the float32 SAD is exact, ties and constant windows are frequent. Ties
    # that are exact in real numbers may come out of the enhancement (means and standard
    # deviations in float64) a rounding error apart, and the library sums unshifted values
    # (module docs of cmal_lcd.matching.seqslam): there either row is right, and the ratio,
    # a quotient of two rounding errors, means nothing.
    features = np.random.default_rng(seed).integers(0, levels, size=(N, F)).astype(np.float32)
    params = SeqSLAMParams.defaults(ds=ds, v_min=v[0], v_max=v[1], v_step=v[2], r_window=r_window,
                           enhance=enhance)
    n_allowed = exclusion_limits(N, frames=frames)
    result = match_loops(features, metric="sad", params=params, n_allowed=n_allowed,
                         keep_matrices=True)
    D, D_hat, (match, score, ratio) = loop_pipeline(features, params=params,
                                                    n_allowed=n_allowed)
    np.testing.assert_array_equal(result.D, D.astype(np.float32))
    np.testing.assert_allclose(result.D_hat, D_hat.astype(np.float32), rtol=1e-6, atol=1e-6)
    tied = rounding_ties(D_hat, match, params)
    np.testing.assert_array_equal(result.match[~tied], match[~tied])
    for T in np.flatnonzero(tied):
        scores = loop_row_scores(D_hat, T, ds=ds, velocities=list(params.velocities()))
        assert scores[result.match[T]] <= score[T] + TOL["atol"]
    np.testing.assert_allclose(result.score, score, **TOL)
    np.testing.assert_allclose(result.ratio[~tied], ratio[~tied], **TOL)
    sf_match, sf_ratio = loop_single_frame(D, r_window=r_window)
    sf_alone = np.array([not any(np.isfinite(D[r, q]) for r in range(N)
                                 if abs(r - sf_match[q]) > r_window // 2) for q in range(N)])
    sf_ratio = np.where(sf_alone, 1.0, sf_ratio)
    has_row = n_allowed > 0
    np.testing.assert_array_equal(result.single_frame_match[has_row], sf_match[has_row])
    np.testing.assert_array_equal(result.single_frame_match[~has_row], -1)
    np.testing.assert_allclose(result.single_frame_ratio[has_row], sf_ratio[has_row], **TOL)
    assert not np.isnan(result.confidence_score[result.match >= 0]).any()


def rounding_ties(D_hat, match, params):
    """``bool (Q,)``: queries whose best score another row equals within float64 rounding.

    Exact ties of the loop count too: the library sums the same values in another order, so
    its two scores can come out an ulp apart either way (seed 252 below: rows 6 and 8 tie
    exactly in the loop, and the library's row 8 is one ulp lower)."""
    tied = np.zeros(len(match), dtype=bool)
    for T in np.flatnonzero(match >= 0):
        scores = np.array(loop_row_scores(D_hat, T, ds=params.ds,
                                          velocities=list(params.velocities())))
        near = np.abs(scores - scores[match[T]]) <= 1e-12 * max(1.0, abs(scores[match[T]]))
        tied[T] = near.sum() > 1
    return tied


def test_a_query_without_competitor_is_least_confident_not_most():
    """Just past the exclusion zone a query has few allowed rows: ratio 1, never 0."""
    features = looping_route(20, laps=1, seed=2)
    result = match_loops(features, metric="sad", params=SeqSLAMParams.defaults(ds=2, r_window=10),
                         n_allowed=exclusion_limits(20, frames=8))
    few = (result.match >= 0) & (result.n_allowed <= 6)  # every row inside the window
    assert few.any()
    np.testing.assert_array_equal(result.ratio[few], 1.0)
    np.testing.assert_array_equal(result.single_frame_ratio[few], 1.0)


def test_no_query_matches_inside_its_exclusion_zone():
    features = looping_route(40, laps=2)
    n_allowed = exclusion_limits(len(features), frames=15)
    result = match_loops(features, metric="sad", params=SeqSLAMParams.defaults(ds=5, r_window=6),
                         n_allowed=n_allowed)
    scored = result.match >= 0
    assert scored.any()
    assert (result.match[scored] < n_allowed[scored]).all()
    assert (result.single_frame_match < np.maximum(n_allowed, 1)).all()


def test_second_lap_matches_the_first_lap():
    n_lap = 40
    features = looping_route(n_lap, laps=2, seed=3)
    result = match_loops(features, metric="sad", params=SeqSLAMParams.defaults(ds=5, r_window=6),
                         n_allowed=exclusion_limits(2 * n_lap, frames=20))
    second_lap = np.arange(n_lap + 5, 2 * n_lap)
    np.testing.assert_array_equal(result.match[second_lap], second_lap - n_lap)


def test_without_exclusion_zone_every_frame_would_match_its_recent_past():
    """The failure the zone prevents: with frames=0 the first lap matches its own last frames."""
    features = looping_route(40, laps=1, noise=0.0, seed=1)
    naive = match_loops(features, metric="sad", params=SeqSLAMParams.defaults(ds=5, r_window=6),
                        n_allowed=exclusion_limits(40, frames=0))
    scored = naive.match >= 0
    assert np.median(np.arange(40)[scored] - naive.match[scored]) <= 2


def test_difference_equals_two_drive_matching_of_the_sequence_with_itself():
    features = looping_route(20, laps=2)
    params = SeqSLAMParams.defaults(ds=4, r_window=0, enhance=False)
    loops = match_loops(features, metric="sad", params=params, keep_matrices=True,
                        n_allowed=exclusion_limits(40, frames=0))
    pair = match_sequences(features, features, metric="sad", params=params, keep_matrices=True)
    allowed = ~exclusion_mask(loops.n_allowed)
    np.testing.assert_array_equal(loops.D[allowed], pair.D[allowed])
    assert np.isinf(loops.D[~allowed]).all()


def test_sqeuclidean_codes_are_accepted():
    codes = looping_route(25, laps=2, dim=8)
    result = match_loops(codes, metric="sqeuclidean", params=SeqSLAMParams.defaults(ds=4, r_window=4),
                         n_allowed=exclusion_limits(50, frames=10))
    second_lap = np.arange(30, 50)
    np.testing.assert_array_equal(result.match[second_lap], second_lap - 25)


@pytest.mark.parametrize("kwargs, name", [({"n_allowed": np.array([0, 2, 1])}, "n_allowed"),
                                          ({"n_allowed": np.zeros(2, int)}, "n_allowed"),
                                          ({"metric": "cosine"}, "metric"),
                                          ({"params": {"ds": 2}}, "params")])
def test_match_loops_rejects_bad_arguments_naming_them(kwargs, name):
    args = {"metric": "sad", **kwargs}
    with pytest.raises(ValueError, match=name):
        match_loops(np.zeros((3, 4), np.float32), **args)
