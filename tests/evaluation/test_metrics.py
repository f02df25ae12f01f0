"""Loop-closure metrics: hand-computed cases, scikit-learn as the external reference, edge cases."""

import logging

import numpy as np
import pytest
from sklearn.metrics import average_precision_score, roc_auc_score
from sklearn.metrics import precision_recall_curve as sk_precision_recall_curve

from cmal_lcd.evaluation import (
    correct_matches,
    loop_closure_metrics,
    precision_recall_curve,
    roc_curve,
)


def test_correct_means_place_present_and_within_d_thresh_inclusive():
    match = np.array([10, 10, 10, -1, 5])
    truth = np.array([12, 13, -1, 4, 5])
    np.testing.assert_array_equal(correct_matches(match, truth, d_thresh=2),
                                  [True, False, False, False, True])


def test_hand_computed_case():
    # queries sorted by confidence: correct, correct, wrong, correct, wrong(place absent)
    match = np.array([0, 1, 50, 3, 4, -1])
    truth = np.array([0, 1, 2, 3, -1, 5])
    confidence = np.array([0.1, 0.2, 0.3, 0.4, 0.5, np.nan])
    m = loop_closure_metrics(match, confidence, truth, d_thresh=0,
                             single_frame_match=np.array([0, 9, 2, 3, 4, 5]))
    # n_scored = 5; positives (truth >= 0 among scored) = 4; correct = 3
    assert (m["n_query"], m["n_scored"], m["n_positive"]) == (6, 5, 4)
    # thresholds: P = 1, 1, 2/3, 3/4, 3/5; R = 1/4, 2/4, 2/4, 3/4, 3/4
    assert m["auc_pr"] == pytest.approx(0.25 * 1 + 0.25 * 1 + 0 + 0.25 * 0.75 + 0)
    assert m["recall_at_100p"] == pytest.approx(0.5)
    assert m["recall_at_1"] == pytest.approx(3 / 5)
    assert m["single_frame_recall_at_1"] == pytest.approx(3 / 5)  # q0, q2, q3 of the scored
    # ROC: correct ranks 1, 2, 4 against incorrect 3, 5: pairs won 2 + 2 + 1 of 6
    assert m["auc_roc"] == pytest.approx(5 / 6)


def test_exact_curve_has_one_point_per_distinct_confidence():
    confidence = np.array([0.3, 0.1, 0.3, 0.2])
    correct = np.array([True, True, False, True])
    precision, recall, thresholds = precision_recall_curve(confidence, correct, n_positive=4)
    np.testing.assert_array_equal(thresholds, [0.1, 0.2, 0.3])
    np.testing.assert_allclose(precision, [1.0, 1.0, 0.75])
    np.testing.assert_allclose(recall, [0.25, 0.5, 0.75])


def test_a_tie_with_a_wrong_match_breaks_perfect_precision():
    match = np.array([0, 1, 2])
    truth = np.array([0, 1, 99])
    m = loop_closure_metrics(match, np.array([0.5, 0.5, 0.9]), truth, d_thresh=0)
    assert m["recall_at_100p"] == pytest.approx(2 / 3)  # the tie group {q0, q1} is correct
    m = loop_closure_metrics(match, np.array([0.5, 0.9, 0.5]), truth, d_thresh=0)
    assert m["recall_at_100p"] == 0.0  # the most confident group holds the wrong q2


@pytest.mark.parametrize("seed", range(12))
def test_agrees_with_scikit_learn_on_random_cases(seed):
    rng = np.random.default_rng(seed)
    Q = int(rng.integers(5, 200))
    truth = np.where(rng.random(Q) < 0.85, rng.integers(0, 300, Q), -1)
    match = np.where(rng.random(Q) < 0.7, truth + rng.integers(-3, 4, Q),
                     rng.integers(0, 300, Q))
    match[rng.random(Q) < 0.1] = -1
    confidence = np.round(rng.random(Q), 2)  # rounding makes ties
    scored = match >= 0
    correct = correct_matches(match, truth, d_thresh=2)[scored]
    n_positive = int((truth[scored] >= 0).sum())
    if correct.all() or not correct.any() or n_positive == 0:
        pytest.skip("degenerate random case")
    m = loop_closure_metrics(match, confidence, truth, d_thresh=2)
    conf = confidence[scored]
    scale = correct.sum() / n_positive  # our recall is over n_positive, sklearn's over n_correct
    assert m["auc_pr"] == pytest.approx(average_precision_score(correct, -conf) * scale)
    assert m["auc_roc"] == pytest.approx(roc_auc_score(correct, -conf))
    sk_p, sk_r, sk_t = sk_precision_recall_curve(correct, -conf)
    precision, recall, thresholds = precision_recall_curve(conf, correct, n_positive=n_positive)
    # sklearn: thresholds ascending in -confidence plus a final (recall 0, precision 1) point
    np.testing.assert_allclose(precision, sk_p[:-1][::-1])
    np.testing.assert_allclose(recall, sk_r[:-1][::-1] * scale)
    np.testing.assert_allclose(thresholds, -sk_t[::-1])
    brute = max([r for p, r in zip(precision, recall) if p == 1.0], default=0.0)
    assert m["recall_at_100p"] == brute
    assert m["recall_at_1"] == pytest.approx(correct.mean())


def test_roc_curve_runs_from_nothing_to_everything_accepted():
    fpr, tpr, thresholds = roc_curve(np.array([0.1, 0.2, 0.3]), np.array([True, False, True]))
    np.testing.assert_allclose(fpr, [0, 0, 1, 1])
    np.testing.assert_allclose(tpr, [0, 0.5, 0.5, 1])
    assert thresholds[0] == -np.inf


def test_queries_whose_place_is_absent_are_negatives():
    match = np.array([0, 1, 2, 3])
    truth = np.array([0, 1, -1, -1])
    m = loop_closure_metrics(match, np.array([0.1, 0.2, 0.3, 0.4]), truth, d_thresh=0)
    assert m["n_positive"] == 2 and m["recall_at_100p"] == 1.0 and m["auc_pr"] == 1.0
    m = loop_closure_metrics(match, np.array([0.3, 0.4, 0.1, 0.2]), truth, d_thresh=0)
    assert m["recall_at_100p"] == 0.0  # accepting an absent place first is a false positive


def test_roc_auc_is_nan_with_a_warning_when_only_one_class(caplog):
    with caplog.at_level(logging.WARNING, logger="cmal_lcd.evaluation.metrics"):
        m = loop_closure_metrics(np.array([0, 1]), np.array([0.1, 0.2]), np.array([0, 1]),
                                 d_thresh=0)
    assert np.isnan(m["auc_roc"]) and "auc_roc" in caplog.text
    assert m["auc_pr"] == 1.0 and m["recall_at_100p"] == 1.0


def test_single_frame_recall_is_nan_when_not_given():
    m = loop_closure_metrics(np.array([0, 5]), np.array([0.1, 0.2]), np.array([0, 1]),
                             d_thresh=0)
    assert np.isnan(m["single_frame_recall_at_1"])


def test_no_scored_query_raises_naming_match():
    with pytest.raises(ValueError, match="match"):
        loop_closure_metrics(np.array([-1, -1]), np.array([np.nan, np.nan]), np.array([0, 1]),
                             d_thresh=20)


def test_no_positive_raises_naming_truth():
    with pytest.raises(ValueError, match="truth"):
        loop_closure_metrics(np.array([0, 1]), np.array([0.1, 0.2]), np.array([-1, -1]),
                             d_thresh=20)


def test_non_finite_confidence_of_a_scored_query_raises():
    with pytest.raises(ValueError, match="confidence"):
        loop_closure_metrics(np.array([0, 1]), np.array([np.nan, 0.2]), np.array([0, 1]),
                             d_thresh=20)


def test_shape_mismatch_raises():
    with pytest.raises(ValueError, match="shape"):
        loop_closure_metrics(np.array([0, 1]), np.array([0.1]), np.array([0, 1]), d_thresh=20)


def test_precision_recall_curve_rejects_a_too_small_n_positive():
    with pytest.raises(ValueError, match="n_positive"):
        precision_recall_curve(np.array([0.1, 0.2]), np.array([True, True]), n_positive=1)
