"""Ground truth from frame correspondence and from poses."""

import numpy as np
import pytest
from scipy.spatial.distance import cdist

from cmal_lcd.evaluation import ground_truth_from_correspondence, ground_truth_from_poses


def test_correspondence_pairs_frames_by_index_and_marks_extra_queries_absent():
    np.testing.assert_array_equal(ground_truth_from_correspondence(3, 5), [0, 1, 2, -1, -1])
    np.testing.assert_array_equal(ground_truth_from_correspondence(5, 3), [0, 1, 2])
    assert ground_truth_from_correspondence(3, 5).dtype == np.int64


def test_correspondence_rejects_negative_lengths():
    with pytest.raises(ValueError, match="n_reference"):
        ground_truth_from_correspondence(-1, 3)


def test_poses_give_the_nearest_reference_within_the_distance():
    reference = np.array([[0.0, 0.0], [10.0, 0.0], [20.0, 0.0]])
    query = np.array([[9.0, 1.0], [19.0, 0.0], [50.0, 0.0], [0.0, 4.0]])
    np.testing.assert_array_equal(ground_truth_from_poses(reference, query, max_distance=5.0),
                                  [1, 2, -1, 0])


def test_the_distance_is_inclusive_and_ties_go_to_the_lowest_index():
    reference = np.array([[0.0, 0.0], [10.0, 0.0]])
    np.testing.assert_array_equal(
        ground_truth_from_poses(reference, np.array([[5.0, 0.0]]), max_distance=5.0), [0])


def test_poses_agree_with_a_brute_force_distance_matrix():
    rng = np.random.default_rng(0)
    reference = rng.uniform(0, 100, (200, 2))
    query = rng.uniform(0, 100, (150, 2))
    d = cdist(query, reference)
    expected = np.where(d.min(axis=1) <= 3.0, d.argmin(axis=1), -1)
    np.testing.assert_array_equal(ground_truth_from_poses(reference, query, max_distance=3.0),
                                  expected)


@pytest.mark.parametrize("reference, query, kwargs, name", [
    (np.zeros((3, 3)), np.zeros((2, 2)), {"max_distance": 1.0}, "reference_xy"),
    (np.zeros((3, 2)), np.full((2, 2), np.nan), {"max_distance": 1.0}, "query_xy"),
    (np.zeros((3, 2)), np.zeros((2, 2)), {"max_distance": -1.0}, "max_distance"),
])
def test_invalid_inputs_raise_naming_them(reference, query, kwargs, name):
    with pytest.raises(ValueError, match=name):
        ground_truth_from_poses(reference, query, **kwargs)
