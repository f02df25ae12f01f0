"""Rules of ``cmal_lcd.evaluation.metrics`` that mutation testing found unchecked by
``tests/evaluation/test_metrics.py`` (see ``docs/testing.md``). Expected values by hand."""

import numpy as np
import pytest

from cmal_lcd.evaluation.metrics import (correct_matches, loop_closure_metrics,
                                         precision_recall_curve, recall_at_k, roc_curve)


@pytest.mark.parametrize("bad", [2.5, True, np.float64(3.0)])
def test_precision_recall_curve_needs_an_integer_number_of_positives(bad):
    with pytest.raises(ValueError, match="n_positive must be an integer"):
        precision_recall_curve(np.array([0.1, 0.2]), np.array([True, False]), n_positive=bad)


def test_correct_matches_names_a_negative_tolerance():
    with pytest.raises(ValueError, match="d_thresh must be >= 0"):
        correct_matches(np.array([1]), np.array([1]), d_thresh=-1)


def test_loop_closure_metrics_reports_recall_at_k_of_both_rankings_over_scored_queries():
    # 4 queries, the last not scored; truth 5, 7, -1, 2; d_thresh 1
    match = np.array([5, 0, 3, -1])
    confidence = np.array([0.9, 0.5, 0.1, np.nan])
    truth = np.array([5, 7, -1, 2])
    top_k = np.array([[5, 0, 0, 0, 0], [0, 0, 8, 0, 0], [3, 4, 5, 6, 7], [2, 2, 2, 2, 2]])
    top_k = np.repeat(top_k, 4, axis=1)  # K_max = 20
    single = np.full((4, 20), 0)
    single[1, 9] = 7  # query 1's true place first appears at rank 10
    out = loop_closure_metrics(match, confidence, truth, d_thresh=1, top_k=top_k,
                               single_frame_top_k=single,
                               single_frame_match=np.array([5, 0, 0, 2]))
    # sequence ranking: query 0 hit at rank 1; query 1 at rank 9 (column 2 repeated 4x -> 8)
    assert out["recall_at_1"] == pytest.approx(1 / 3)
    assert out["recall_at_5"] == pytest.approx(1 / 3)
    assert out["recall_at_10"] == pytest.approx(2 / 3)
    assert out["recall_at_20"] == pytest.approx(2 / 3)
    # single-frame ranking: nobody at ranks 1-9, query 1 at rank 10
    assert out["single_frame_recall_at_5"] == 0.0
    assert out["single_frame_recall_at_10"] == pytest.approx(1 / 3)
    assert out["single_frame_recall_at_1"] == pytest.approx(1 / 3)  # from single_frame_match
    assert (out["n_query"], out["n_scored"], out["n_positive"]) == (4, 3, 2)


def test_precision_recall_curve_accepts_a_single_positive():
    precision, recall, _ = precision_recall_curve(np.array([0.1, 0.2]), np.array([True, False]),
                                                  n_positive=1)
    # ascending thresholds: accept 0.1 (1 TP), then also 0.2 (1 TP, 1 FP)
    np.testing.assert_allclose(precision, [1.0, 0.5])
    np.testing.assert_allclose(recall, [1.0, 1.0])


@pytest.mark.parametrize("confidence, correct, message", [
    (np.zeros(0), np.zeros(0, bool), "confidence is empty"),
    (np.zeros((2, 2)), np.zeros((2, 2), bool), "1-D of the same length"),
    (np.array([0.1, np.nan]), np.array([True, False]), "NaN or infinite"),
])
def test_scores_must_be_a_non_empty_finite_vector(confidence, correct, message):
    with pytest.raises(ValueError, match=message):
        roc_curve(confidence, correct)


@pytest.mark.parametrize("labels, undefined", [([False, False, False], "tpr"),
                                               ([True, True, True], "fpr")])
def test_roc_rate_of_a_missing_class_is_nan_at_every_threshold(labels, undefined):
    """Three distinct confidences -> 4 points (nothing accepted, then each threshold)."""
    fpr, tpr, thresholds = roc_curve(np.array([0.3, 0.1, 0.2]), np.array(labels))
    rates = {"fpr": fpr, "tpr": tpr}
    assert len(thresholds) == len(fpr) == len(tpr) == 4
    assert np.isnan(rates[undefined]).all()
    other = rates["fpr" if undefined == "tpr" else "tpr"]
    np.testing.assert_allclose(other, [0, 1 / 3, 2 / 3, 1])


def test_recall_at_k_counts_a_true_place_at_reference_row_0():
    """Row 0 is a place like any other (-1, not 0, means "none")."""
    top_k = np.array([[0, 5], [3, 0], [-1, -1]])
    truth = np.array([0, 0, 0])
    assert recall_at_k(top_k, truth, d_thresh=0, ks=[1, 2]) == {1: pytest.approx(1 / 3),
                                                                 2: pytest.approx(2 / 3)}
