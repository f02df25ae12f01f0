"""Code normalisation: centring statistics never come from the query drive."""

import numpy as np
import pytest

from cmal_lcd.matching.normalise import (CodeNormalisation, centring_sample, condition_means,
                                         l2_normalise, nearest_condition, normalise_pair)

ALL = [CodeNormalisation(c, l2) for c in ("none", "reference", "condition")
       for l2 in (False, True)]


def drives(seed=0, n=30, f=8):
    rng = np.random.default_rng(seed)
    places = rng.normal(size=(n, f))
    offsets = rng.normal(size=(3, f)) * 20  # one offset per weather
    reference = (places + offsets[0]).astype(np.float32)
    query = (places + offsets[1] + 0.1 * rng.normal(size=(n, f))).astype(np.float32)
    train = np.concatenate([rng.normal(size=(50, f)) + offsets[k] for k in range(3)])
    labels = np.repeat(np.arange(3), 50)
    return reference, query, condition_means(train, labels, 3)


@pytest.mark.parametrize("norm", ALL, ids=lambda n: n.label)
def test_permuting_or_truncating_the_query_drive_changes_no_other_row(norm):
    reference, query, means = drives()
    ref_a, q_a = normalise_pair(reference, query, norm, train_means=means)
    order = np.random.default_rng(3).permutation(len(query))
    ref_b, q_b = normalise_pair(reference, query[order], norm, train_means=means)
    np.testing.assert_array_equal(ref_a, ref_b)
    np.testing.assert_allclose(q_b, q_a[order], rtol=1e-6, atol=1e-6)
    _, q_c = normalise_pair(reference, query[:7], norm, train_means=means)
    np.testing.assert_allclose(q_c, q_a[:7], rtol=1e-6, atol=1e-6)


def test_condition_centring_removes_each_weathers_offset():
    reference, query, means = drives()
    ref, qry = normalise_pair(reference, query, CodeNormalisation("condition"), train_means=means)
    raw_gap = np.linalg.norm(reference.mean(0) - query.mean(0))
    assert np.linalg.norm(ref.mean(0) - qry.mean(0)) < 0.2 * raw_gap
    np.testing.assert_array_equal(nearest_condition(reference, means), 0)
    np.testing.assert_array_equal(nearest_condition(query, means), 1)


def test_reference_centring_uses_the_map_mean_for_both_drives():
    reference, query, _ = drives()
    ref, qry = normalise_pair(reference, query, CodeNormalisation("reference"))
    np.testing.assert_allclose(ref.mean(0), 0, atol=1e-5)
    np.testing.assert_allclose(qry, query - reference.astype(np.float64).mean(0), rtol=1e-5,
                               atol=1e-4)


def test_raw_codes_pass_through_untouched():
    reference, query, _ = drives()
    ref, qry = normalise_pair(reference, query, CodeNormalisation())
    assert ref is reference and qry is query


def test_l2_gives_unit_rows_and_keeps_zero_rows_zero():
    out = l2_normalise(np.array([[3.0, 4.0], [0.0, 0.0]]))
    np.testing.assert_allclose(out, [[0.6, 0.8], [0.0, 0.0]])


def test_condition_centring_needs_training_statistics():
    reference, query, _ = drives()
    with pytest.raises(ValueError, match="train_means"):
        normalise_pair(reference, query, CodeNormalisation("condition"))


def test_a_condition_without_training_frames_is_named():
    with pytest.raises(ValueError, match="condition 1"):
        condition_means(np.ones((4, 2)), np.array([0, 0, 2, 2]), 3)


def test_unknown_centre_is_refused():
    with pytest.raises(ValueError, match="centre"):
        CodeNormalisation("query")


def test_the_centring_sample_is_evenly_spaced_per_condition_and_in_frame_order():
    rows, labels = centring_sample(
        ["a", "b"], ["a", "b", "a", "a", "b", "a", "a"], per_condition=3)
    np.testing.assert_array_equal(rows, [0, 1, 3, 4, 6])
    np.testing.assert_array_equal(labels, [0, 1, 0, 1, 0])
