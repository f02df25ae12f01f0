"""Ground truth and metrics of loop closure within one traversal, against plain loops."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cmal_lcd.evaluation import loop_closure_metrics
from cmal_lcd.data.ground_truth import loop_ground_truth_from_poses, revisit_nearest_to
from cmal_lcd.evaluation.loops import evaluate_loops
from cmal_lcd.matching import SeqSLAMParams
from cmal_lcd.matching.loops import LoopResult, exclusion_limits, match_loops


def loop_revisits(xy, q, *, tol, n_allowed):
    return [r for r in range(int(n_allowed[q]))
            if math.dist(xy[r], xy[q]) <= tol]


def circuit(n_lap, laps, radius=50.0):
    """Positions around a circle of ``n_lap`` frames, driven ``laps`` times."""
    angle = 2 * np.pi * np.arange(n_lap * laps) / n_lap
    return np.stack([radius * np.cos(angle), radius * np.sin(angle)], axis=1)


@given(N=st.integers(1, 25), tol=st.floats(0, 4), frames=st.integers(0, 6),
       seed=st.integers(0, 2**16))
@settings(max_examples=60, deadline=None)
def test_ground_truth_equals_the_loop(N, tol, frames, seed):
    rng = np.random.default_rng(seed)
    xy = rng.integers(0, 5, size=(N, 2)).astype(float)  # many revisits and distance ties
    n_allowed = exclusion_limits(N, frames=frames)
    match = rng.integers(-1, N, size=N)
    truth = loop_ground_truth_from_poses(xy, pose_tolerance=tol, n_allowed=n_allowed)
    near = revisit_nearest_to(match, xy, pose_tolerance=tol, n_allowed=n_allowed)
    for q in range(N):
        revisits = loop_revisits(xy, q, tol=tol, n_allowed=n_allowed)
        if not revisits:
            assert truth[q] == -1 and near[q] == -1
            continue
        assert truth[q] == min(revisits, key=lambda r: (math.dist(xy[r], xy[q]), r))
        key = ((lambda r: (abs(r - match[q]), r)) if match[q] >= 0
               else (lambda r: (math.dist(xy[r], xy[q]), r)))
        assert near[q] == min(revisits, key=key)


def test_first_lap_is_negative_and_second_lap_revisits_it():
    xy = circuit(20, 2)
    truth = loop_ground_truth_from_poses(xy, pose_tolerance=1.0,
                                         n_allowed=exclusion_limits(40, frames=5))
    np.testing.assert_array_equal(truth[:20], -1)
    np.testing.assert_array_equal(truth[20:], np.arange(20))


def test_a_revisit_inside_the_exclusion_zone_is_not_a_revisit():
    xy = np.zeros((6, 2))  # standing still: every earlier frame is at the same place
    truth = loop_ground_truth_from_poses(xy, pose_tolerance=1.0,
                                         n_allowed=exclusion_limits(6, frames=3))
    np.testing.assert_array_equal(truth, [-1, -1, -1, -1, 0, 0])


def fake_result(match, confidence, n_allowed, sf=None):
    match = np.asarray(match, np.int64)
    return LoopResult(match=match, score=np.asarray(confidence, float),
                      ratio=np.asarray(confidence, float),
                      single_frame_match=match if sf is None else np.asarray(sf, np.int64),
                      single_frame_ratio=np.zeros(match.size), n_allowed=n_allowed,
                      params=SeqSLAMParams.defaults())


def test_a_match_on_any_earlier_lap_is_correct():
    xy = circuit(10, 3)
    n_allowed = exclusion_limits(30, frames=3)
    match = np.full(30, -1)
    conf = np.full(30, np.nan)
    match[25], conf[25] = 5, 0.1    # first lap: correct
    match[26], conf[26] = 16, 0.2   # second lap: correct
    match[27], conf[27] = 12, 0.3   # wrong place (5 frames off)
    match[5], conf[5] = 0, 0.05     # first lap has no revisit: a false positive
    ev = evaluate_loops(fake_result(match, conf, n_allowed), xy, pose_tolerance=1.0, d_thresh=1)
    np.testing.assert_array_equal(np.flatnonzero(ev.correct), [25, 26])
    assert ev.metrics["n_scored"] == 4 and ev.metrics["n_positive"] == 3
    assert ev.metrics["recall_at_100p"] == 0.0  # the most confident one is a false positive
    assert ev.metrics["recall_at_1"] == pytest.approx(2 / 4)
    assert ev.metrics["n_revisit"] == 20


def test_metrics_are_loop_closure_metrics_with_the_per_match_truth():
    xy = circuit(15, 2)
    features = np.concatenate([np.eye(15, 16)] * 2).astype(np.float32) * 10
    result = match_loops(features, metric="sad", params=SeqSLAMParams.defaults(ds=3, r_window=4),
                         n_allowed=exclusion_limits(30, frames=5))
    ev = evaluate_loops(result, xy, pose_tolerance=1.0, d_thresh=0)
    truth = np.where(np.arange(30) >= 15, np.arange(30) - 15, -1)  # one revisit per frame
    expected = loop_closure_metrics(result.match, result.confidence_score, truth, d_thresh=0)
    for key, value in expected.items():
        if key != "single_frame_recall_at_1":
            assert ev.metrics[key] == pytest.approx(value, nan_ok=True), key
    scored = np.flatnonzero(result.match >= 0)
    assert scored.size >= 10 and (scored >= 15).all()  # first-lap frames: constant windows
    np.testing.assert_array_equal(result.match[scored], scored - 15)
    assert ev.metrics["recall_at_1"] == 1.0


def test_no_revisit_at_all_raises_naming_the_poses():
    xy = np.stack([np.arange(20.0), np.zeros(20)], axis=1)  # a straight line
    result = fake_result(np.r_[np.full(10, -1), np.zeros(10, int)], np.r_[np.full(10, np.nan),
                                                                          np.ones(10)],
                         exclusion_limits(20, frames=2))
    with pytest.raises(ValueError, match="poses.*revisit"):
        evaluate_loops(result, xy, pose_tolerance=0.5, d_thresh=2)


@pytest.mark.parametrize("kwargs, name", [({"pose_tolerance": -1.0}, "pose_tolerance"),
                                          ({"n_allowed": np.zeros(2, int)}, "n_allowed")])
def test_ground_truth_rejects_bad_arguments_naming_them(kwargs, name):
    args = {"pose_tolerance": 1.0, "n_allowed": np.zeros(3, int), **kwargs}
    with pytest.raises(ValueError, match=name):
        loop_ground_truth_from_poses(np.zeros((3, 2)), **args)


def test_a_loop_match_at_frame_0_is_scored_and_every_curve_is_returned():
    """The 2026-12-01 evaluation/ mutation run: frame 5's match is reference row 0 (a false
    positive, the first lap has no revisit), so it counts among the 4 scored frames for the
    single-frame recall@1 (2 of 4 correct) and is the first point of the PR curve. Expected
    values by hand: confidences ascending 0.05 (wrong), 0.1, 0.2 (correct), 0.3 (wrong),
    3 true loop closures among the scored frames."""
    xy = circuit(10, 3)
    n_allowed = exclusion_limits(30, frames=3)
    match = np.full(30, -1)
    conf = np.full(30, np.nan)
    match[25], conf[25] = 5, 0.1
    match[26], conf[26] = 16, 0.2
    match[27], conf[27] = 12, 0.3
    match[5], conf[5] = 0, 0.05
    ev = evaluate_loops(fake_result(match, conf, n_allowed), xy, pose_tolerance=1.0, d_thresh=1)
    assert ev.metrics["single_frame_recall_at_1"] == 0.5
    np.testing.assert_allclose(ev.thresholds, [0.05, 0.1, 0.2, 0.3])
    np.testing.assert_allclose(ev.precision, [0.0, 1 / 2, 2 / 3, 2 / 4])
    np.testing.assert_allclose(ev.recall, [0.0, 1 / 3, 2 / 3, 2 / 3])
    np.testing.assert_array_equal(ev.truth[:10], -1)  # the first lap has no earlier frame
    np.testing.assert_array_equal(ev.truth[10:20], np.arange(10))
    assert (ev.truth[20:] % 10 == np.arange(20, 30) % 10).all()
