"""cross_weather_separation: same place vs other places, both across weathers."""

import numpy as np
import pytest

from cmal_lcd.evaluation.invariance import cross_weather_separation


def brute_force(D, truth, d_thresh):
    same, other, hits = [], [], []
    for q, t in enumerate(truth):
        if t < 0:
            continue
        same.append(D[t, q])
        other += [D[r, q] for r in range(D.shape[0]) if abs(r - t) > d_thresh]
        hits.append(abs(int(np.argmin(D[:, q])) - t) <= d_thresh)
    return np.mean(same), np.mean(other), np.mean(hits)


def test_matches_the_definition_on_random_matrices():
    rng = np.random.default_rng(0)
    for _ in range(20):
        R, Q = rng.integers(5, 30, size=2)
        D = rng.uniform(0, 5, size=(R, Q))
        truth = rng.integers(-1, R, size=Q)
        d_thresh = int(rng.integers(0, 4))
        stats = cross_weather_separation(D, truth, d_thresh=d_thresh)
        if not (truth >= 0).any():
            assert stats["n_queries"] == 0
            continue
        same, other, r1 = brute_force(D, truth, d_thresh)
        assert stats["same_place"] == pytest.approx(same)
        assert stats["other_place"] == pytest.approx(other)
        assert stats["ratio"] == pytest.approx(same / other)
        assert stats["single_frame_recall_at_1"] == pytest.approx(r1)


def test_a_place_code_has_a_low_ratio_and_a_weather_offset_does_not_matter():
    rng = np.random.default_rng(1)
    places = rng.normal(size=(40, 16))
    reference = places + 0.05 * rng.normal(size=places.shape)
    query = places + 0.05 * rng.normal(size=places.shape) + 10.0  # a large weather offset
    truth = np.arange(40)
    centred = cross_weather_separation(
        ((reference - reference.mean(0))[:, None, :] - (query - query.mean(0))[None, :, :]) ** 2
        @ np.ones(16), truth, d_thresh=0)
    assert centred["ratio"] < 0.1
    assert centred["single_frame_recall_at_1"] == 1.0


def test_queries_without_a_true_place_give_nan_not_an_error():
    stats = cross_weather_separation(np.ones((3, 2)), np.array([-1, -1]), d_thresh=1)
    assert stats["n_queries"] == 0 and np.isnan(stats["ratio"])


def test_rejects_mismatched_shapes_and_non_finite_differences():
    with pytest.raises(ValueError, match="D/truth"):
        cross_weather_separation(np.ones((3, 2)), np.zeros(3, int), d_thresh=1)
    with pytest.raises(ValueError, match="finite"):
        cross_weather_separation(np.full((3, 2), np.inf), np.zeros(2, int), d_thresh=1)
