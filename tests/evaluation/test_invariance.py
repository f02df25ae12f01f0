"""code_invariance: same place across weathers vs different places in one weather."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cmal_lcd.evaluation.invariance import code_invariance


def brute_force(codes, place, condition):
    """Every unordered pair, by the definition."""
    same, diff = [], []
    for i in range(len(codes)):
        for j in range(i + 1, len(codes)):
            d = float(np.sum((codes[i] - codes[j]) ** 2))
            if place[i] == place[j] and condition[i] != condition[j]:
                same.append(d)
            if place[i] != place[j] and condition[i] == condition[j]:
                diff.append(d)
    return (np.mean(same) if same else np.nan, np.mean(diff) if diff else np.nan,
            len(same), len(diff))


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 10_000), st.integers(1, 25), st.integers(1, 6), st.integers(1, 4),
       st.integers(1, 3))
def test_matches_the_pairwise_definition(seed, n, dim, n_places, n_conditions):
    rng = np.random.default_rng(seed)
    codes = rng.normal(size=(n, dim)) * rng.uniform(0.1, 100) + rng.normal(size=dim) * 50
    place = rng.integers(0, n_places, n)
    condition = rng.integers(0, n_conditions, n)
    stats = code_invariance(codes, place, condition)
    same, diff, n_same, n_diff = brute_force(codes, place, condition)
    assert stats["n_pairs_same_place"] == n_same
    assert stats["n_pairs_different_place"] == n_diff
    np.testing.assert_allclose(stats["same_place_cross_condition"], same, rtol=1e-7, atol=1e-7)
    np.testing.assert_allclose(stats["different_place_same_condition"], diff, rtol=1e-7,
                               atol=1e-7)


def grid(n_places=20, n_conditions=3, *, place_scale, condition_scale, dim=32, seed=0):
    """Codes = place signature * place_scale + weather signature * condition_scale + noise."""
    rng = np.random.default_rng(seed)
    place = np.repeat(np.arange(n_places), n_conditions)
    condition = np.tile(np.arange(n_conditions), n_places)
    codes = (rng.normal(size=(n_places, dim))[place] * place_scale
             + rng.normal(size=(n_conditions, dim))[condition] * condition_scale
             + rng.normal(size=(len(place), dim)) * 0.01)
    return codes, place, condition


def test_a_place_code_is_invariant_and_a_weather_code_is_not():
    invariant = code_invariance(*grid(place_scale=1.0, condition_scale=0.1))
    weather = code_invariance(*grid(place_scale=0.1, condition_scale=1.0))
    assert invariant["ratio"] < 0.1
    assert weather["ratio"] > 10
    assert invariant["same_place_cross_condition"] < invariant["different_place_same_condition"]


def test_ratio_ignores_scale_and_shift_of_the_codes():
    codes, place, condition = grid(place_scale=1.0, condition_scale=0.5)
    base = code_invariance(codes, place, condition)
    moved = code_invariance(codes * 1e3 + 7.0, place, condition)
    assert moved["ratio"] == pytest.approx(base["ratio"], rel=1e-9)
    assert moved["same_place_cross_condition"] == pytest.approx(
        base["same_place_cross_condition"] * 1e6, rel=1e-9)


def test_without_pairs_the_means_are_nan():
    stats = code_invariance(np.ones((3, 2)), np.array([0, 1, 2]), np.array([0, 0, 0]))
    assert np.isnan(stats["same_place_cross_condition"]) and np.isnan(stats["ratio"])
    assert stats["different_place_same_condition"] == 0.0
    assert stats["n_pairs_same_place"] == 0 and stats["n_pairs_different_place"] == 3


@pytest.mark.parametrize("codes, place, condition, name", [
    (np.zeros(4), np.zeros(4, int), np.zeros(4, int), "codes"),
    (np.zeros((4, 2)), np.zeros(3, int), np.zeros(4, int), "place"),
    (np.zeros((4, 2)), np.zeros(4, int), np.zeros(4), "condition"),
    (np.full((4, 2), np.nan), np.zeros(4, int), np.zeros(4, int), "codes"),
])
def test_bad_inputs_are_named(codes, place, condition, name):
    with pytest.raises(ValueError, match=name):
        code_invariance(codes, place, condition)
