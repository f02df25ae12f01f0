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


def _pair(n=40, seed=5):
    rng = np.random.default_rng(seed)
    reference = rng.normal(size=(n, 16))
    return reference, reference + 0.05 * rng.normal(size=(n, 16))


def test_the_pr_curve_of_a_pair_scores_exactly_the_correct_matches():
    """The curve behind Figs. 8-9 (``evaluate_pair``'s precision/recall, computed apart from
    the metrics) counts a match correct iff it is scored, its query has a true place, and it
    lies within ``d_thresh`` frames, boundary included. Kills ``< d_thresh``, ``|`` for ``&``,
    ``truth > 0`` and ``match + truth`` in that computation (the metrics have their own)."""
    from cmal_lcd.evaluation.loop_closure import evaluate_pair
    from cmal_lcd.evaluation.metrics import precision_recall_curve
    from cmal_lcd.matching import SeqSLAMParams

    reference, query = _pair()
    params = SeqSLAMParams(ds=3, enhance=False)
    d = 4
    first = evaluate_pair(reference, query, np.arange(len(query)), metric="sqeuclidean",
                          params=params, d_thresh=d)
    match = first.result.match
    scored = np.flatnonzero(match >= 0)
    lowest = scored[np.argmin(match[scored])]
    at_d = scored[match[scored] == d]
    assert len(scored) > 10 and match[lowest] + 1 <= d and len(at_d) == 1
    truth = match.copy()                                 # every scored match correct, except:
    truth[lowest] = -1                                   # no true place, though |m - (-1)| <= d
    truth[at_d[0]] = 0                                   # true place at row 0, d_thresh away
    others = [q for q in scored if q not in (lowest, at_d[0])]
    truth[others[0]] = match[others[0]] + d              # exactly d_thresh away: correct
    truth[others[1]] = match[others[1]] + d + 1          # one frame beyond: wrong
    evaluation = evaluate_pair(reference, query, truth, metric="sqeuclidean", params=params,
                               d_thresh=d)
    np.testing.assert_array_equal(evaluation.result.match, match)
    has_place = truth >= 0
    correct = (match >= 0) & has_place & (np.abs(match - truth) <= d)
    assert correct[others[0]] and correct[at_d[0]] and not correct[others[1]]
    keep = match >= 0
    expected = precision_recall_curve(evaluation.result.confidence_score[keep], correct[keep],
                                      n_positive=int((keep & has_place).sum()))
    for got, want in zip((evaluation.precision, evaluation.recall, evaluation.thresholds),
                         expected):
        np.testing.assert_array_equal(got, want)


# --- matching protocols ------------------------------------------------------------------------

def test_the_paper_protocol_is_raw_codes_with_eq14_at_the_table_i_window():
    """Kills an L2 or a disabled enhancement in the paper's protocol (the ablation)."""
    from cmal_lcd.evaluation.protocol import paper_protocol
    from cmal_lcd.matching import SeqSLAMParams

    protocol = paper_protocol(SeqSLAMParams(r_window=14))
    assert protocol.normalisation.centre == "none" and protocol.normalisation.l2 is False
    assert protocol.enhance is True and protocol.r_window == 14


@pytest.mark.parametrize("enhance", [True, False])
def test_a_protocol_sets_enhancement_and_window_of_the_search(enhance):
    """Kills ``enhance=None`` / a dropped ``enhance`` in ``MatchingProtocol.seqslam``."""
    from cmal_lcd.evaluation.protocol import MatchingProtocol
    from cmal_lcd.matching import SeqSLAMParams
    from cmal_lcd.matching.normalise import CodeNormalisation

    params = SeqSLAMParams(ds=7, enhance=not enhance, r_window=10)
    got = MatchingProtocol(CodeNormalisation("none"), enhance=enhance, r_window=4).seqslam(params)
    assert got.enhance is enhance and got.r_window == 4 and got.ds == 7


def test_a_full_tie_between_protocols_goes_to_the_earlier_candidate():
    """Kills ``+i`` for ``-i`` in the tie-break (equal criterion and equal AUC-PR)."""
    from cmal_lcd.evaluation.protocol import MatchingProtocol, select_protocol
    from cmal_lcd.matching.normalise import CodeNormalisation

    a = MatchingProtocol(CodeNormalisation("reference", True), enhance=False, r_window=10)
    b = MatchingProtocol(CodeNormalisation("condition", True), enhance=True, r_window=10)
    tie = [{"recall_at_100p": 0.6, "auc_pr": 0.8}]
    assert select_protocol([a, b], lambda p: tie)[0] == a
    assert select_protocol([b, a], lambda p: tie)[0] == b


# --- the validation monitor (model selection) --------------------------------------------------

def test_the_monitor_scores_under_its_protocol_with_training_centring_means():
    """Checks only the wrapper: ``ValidationMonitor.score`` is the mean of
    ``evaluate_drive_pairs`` under ``MONITOR_PROTOCOL`` with the condition means of the
    centring codes, not raw codes (kills ``protocol=None`` and a dropped ``protocol``)."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from monitor_helpers import monitor_for, validation_drives

    from cmal_lcd.evaluation.loop_closure import evaluate_drive_pairs
    from cmal_lcd.evaluation.monitor import MONITOR_METRICS, MONITOR_PROTOCOL
    from cmal_lcd.matching.normalise import condition_means

    images, frames, pairs = validation_drives()
    monitor = monitor_for(images, frames, pairs)
    rng = np.random.default_rng(7)
    places = rng.normal(size=(40, 8))
    offset = 25.0 * rng.normal(size=8)                   # drive b: one weather's offset
    val_codes = np.concatenate([places, places + offset])
    centring = rng.normal(size=(len(monitor.centring_labels), 8))
    centring[monitor.centring_labels == 1] += offset     # that weather's training codes
    means = condition_means(centring, monitor.centring_labels, monitor.n_conditions)

    def mean_metrics(protocol):
        rows = [e.metrics for *_, e in evaluate_drive_pairs(
            val_codes, frames, pairs, metric="sqeuclidean", params=monitor.params,
            d_thresh=monitor.d_thresh, ground_truth=monitor.ground_truth,
            pose_tolerance=monitor.pose_tolerance, protocol=protocol, train_means=means,
            progress=None)]
        return {f"val/{k}": float(np.mean([r[k] for r in rows])) for k in MONITOR_METRICS}

    got = monitor.score(val_codes, centring)
    assert got == pytest.approx(mean_metrics(MONITOR_PROTOCOL))
    assert got != pytest.approx(mean_metrics(None))      # the data tell the two apart

