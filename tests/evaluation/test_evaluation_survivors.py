"""Specifications the mutation run over ``evaluation/`` showed were missing (docs/testing.md).

Expected values are written out by hand.
"""

import numpy as np
import pytest

from cmal_lcd.evaluation.ground_truth import (ground_truth_from_correspondence,
                                              ground_truth_from_poses)


def test_index_ground_truth_accepts_empty_drives():
    """Kills ``<= 0`` / ``< 1`` for ``< 0``: a drive of length 0 is valid, not an error."""
    assert ground_truth_from_correspondence(0, 3).tolist() == [-1, -1, -1]
    assert ground_truth_from_correspondence(2, 0).tolist() == []


def test_index_ground_truth_refuses_a_negative_length_and_a_bool():
    """Kills ``and`` for ``or`` in the check."""
    with pytest.raises(ValueError, match="n_reference must be a non-negative integer"):
        ground_truth_from_correspondence(-1, 3)
    with pytest.raises(ValueError, match="n_query must be a non-negative integer"):
        ground_truth_from_correspondence(3, True)


def test_pose_ground_truth_with_zero_tolerance_keeps_exact_revisits_only():
    """Kills ``<= 0`` / ``< 1`` for ``< 0``: a tolerance of 0 m is valid."""
    reference = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]])
    query = np.array([[1.0, 0.0], [1.5, 0.0], [0.0, 0.0]])
    assert ground_truth_from_poses(reference, query, max_distance=0.0).tolist() == [1, -1, 0]
    assert ground_truth_from_poses(reference, query, max_distance=0.5).tolist() == [1, 1, 0]
