"""Specifications the mutation run over ``evaluation/`` showed were missing (docs/testing.md).

Expected values are written out by hand.
"""

import numpy as np
import pytest

from cmal_lcd.data.ground_truth import (ground_truth_from_correspondence,
                                              ground_truth_from_poses,
                                              loop_ground_truth_from_poses, revisit_nearest_to)


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
    params = SeqSLAMParams.defaults(ds=3, enhance=False)
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

    protocol = paper_protocol(SeqSLAMParams.defaults(r_window=14))
    assert protocol.normalisation.centre == "none" and protocol.normalisation.l2 is False
    assert protocol.enhance is True and protocol.r_window == 14


@pytest.mark.parametrize("enhance", [True, False])
def test_a_protocol_sets_enhancement_and_window_of_the_search(enhance):
    """Kills ``enhance=None`` / a dropped ``enhance`` in ``MatchingProtocol.seqslam``."""
    from cmal_lcd.evaluation.protocol import MatchingProtocol
    from cmal_lcd.matching import SeqSLAMParams
    from cmal_lcd.matching.normalise import CodeNormalisation

    params = SeqSLAMParams.defaults(ds=7, enhance=not enhance, r_window=10)
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


def test_each_candidates_row_keeps_its_per_pair_scores_under_pairs():
    """The protocol record (``data/protocol/<method>.json``) holds every candidate's per-pair
    validation scores under ``pairs``, beside the protocol's fields and the two means; the
    2026-12-01 evaluation/ run let a renamed key through."""
    from cmal_lcd.evaluation.protocol import MatchingProtocol, select_protocol
    from cmal_lcd.matching.normalise import CodeNormalisation

    a = MatchingProtocol(CodeNormalisation("reference", True), enhance=False, r_window=10)
    scores = [{"recall_at_100p": 0.6, "auc_pr": 0.8}, {"recall_at_100p": 0.2, "auc_pr": 0.4}]
    _, (row,) = select_protocol([a], lambda p: scores)
    assert row["pairs"] == scores
    assert row["mean_recall_at_100p"] == pytest.approx(0.4)
    assert row["mean_auc_pr"] == pytest.approx(0.6)
    assert set(row) == {*a.as_dict(), "mean_recall_at_100p", "mean_auc_pr", "pairs"}


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



# --- second evaluation run (2026-12-01): fixed examples for the boundaries it still found ---

def _row_zero_pair():
    """Queries 2 and 3 match reference row 0 (a slow trajectory, 0.1 rows per query frame);
    queries 4 and 5 match rows 5 and 7."""
    from cmal_lcd.matching import SeqSLAMParams

    rng = np.random.default_rng(0)
    reference = rng.random((10, 8))
    query = np.stack([reference[i] for i in (0, 0, 0, 5, 6, 7)]) + 0.01
    params = SeqSLAMParams.defaults(ds=2, v_min=0.1, v_max=0.1, v_step=0.1, r_window=0, enhance=False)
    return reference, query, params


def test_a_scored_match_at_reference_row_0_is_on_the_pr_curve():
    """Row 0 is a match like any other: the curve counts it (kills ``match > 0`` and
    ``match >= 1`` for ``match >= 0`` in ``evaluate_pair``). Written out by hand: queries
    2-5 are scored, 2 is correct at row 0, 3 is wrong at row 0 (true place 3), 4 and 5 are
    correct; four positives."""
    from cmal_lcd.evaluation.loop_closure import evaluate_pair

    reference, query, params = _row_zero_pair()
    evaluation = evaluate_pair(reference, query, np.array([-1, -1, 0, 3, 5, 7]),
                               metric="sqeuclidean", params=params, d_thresh=1)
    assert evaluation.result.match.tolist() == [-1, -1, 0, 0, 5, 7]
    # confidence order (lower first): q2 (correct), q3 (wrong), q5, q4 (both correct)
    np.testing.assert_allclose(evaluation.recall, [1 / 4, 1 / 4, 2 / 4, 3 / 4])
    np.testing.assert_allclose(evaluation.precision, [1, 1 / 2, 2 / 3, 3 / 4])


def test_one_positive_query_gives_a_pr_curve():
    """Kills ``n_positive > 1``: a single scored query with a true place has a curve."""
    from cmal_lcd.evaluation.loop_closure import evaluate_pair

    reference, query, params = _row_zero_pair()
    evaluation = evaluate_pair(reference, query, np.array([-1, -1, -1, -1, 5, -1]),
                               metric="sqeuclidean", params=params, d_thresh=1)
    # confidence order q2, q3, q5, q4: only q4 (the last) is correct, the one positive
    np.testing.assert_allclose(evaluation.recall, [0, 0, 0, 1])
    np.testing.assert_allclose(evaluation.precision, [0, 0, 0, 1 / 4])


def _frames(drives):
    import pandas as pd

    rows = [{"drive": d, "x": float(i), "y": 0.0} for d, n in drives for i in range(n)]
    return pd.DataFrame(rows)


@pytest.mark.parametrize("reference, query", [("r/a", "r/empty"), ("r/empty", "r/b")])
def test_a_pair_with_one_empty_drive_is_refused_naming_both_drives(reference, query):
    """Either drive empty is an error (kills ``and`` for ``or``, and ``== 1``)."""
    from cmal_lcd.evaluation.loop_closure import evaluate_drive_pairs
    from cmal_lcd.matching import SeqSLAMParams

    frames = _frames([("r/a", 6), ("r/b", 6)])
    codes = np.random.default_rng(0).random((len(frames), 4))
    pairs = [["r", reference, query, "a-b"]]
    with pytest.raises(ValueError, match=r"pair a-b of r names a drive with no frames "
                                         r"\('r/\w+': \d, 'r/\w+': \d\)"):
        list(evaluate_drive_pairs(codes, frames, pairs, metric="sqeuclidean",
                                  params=SeqSLAMParams.defaults(ds=2, enhance=False), d_thresh=1,
                                  ground_truth="poses", pose_tolerance=0.5))


def test_one_frame_drives_are_matched_not_refused_as_empty():
    """Kills ``== 1`` for ``== 0``: one frame is few, not none (the search says so itself)."""
    from cmal_lcd.evaluation.loop_closure import evaluate_drive_pairs
    from cmal_lcd.matching import SeqSLAMParams

    frames = _frames([("r/a", 1), ("r/b", 6)])
    codes = np.random.default_rng(0).random((len(frames), 4))
    with pytest.raises(ValueError) as err:
        list(evaluate_drive_pairs(codes, frames, [["r", "r/a", "r/b", "a-b"]],
                                  metric="sqeuclidean", params=SeqSLAMParams.defaults(ds=2, enhance=False),
                                  d_thresh=1, ground_truth="poses", pose_tolerance=0.5))
    assert "no frames" not in str(err.value) and str(err.value).startswith("r a-b: ")


def test_pose_ground_truth_over_several_chunks_equals_brute_force():
    """A reference long enough that the query rows are taken two at a time (the chunking of
    ``ground_truth_from_poses``): every chunk is filled (kills iterating over ``shape[1]``)."""
    reference = np.zeros((2**21, 2))
    reference[:, 0] = np.arange(2**21, dtype=np.float64)
    query = np.array([[3.2, 0.0], [7.9, 0.1], [2**21 + 9.0, 0.0], [100.4, 0.0], [0.0, 0.3]])
    truth = ground_truth_from_poses(reference, query, max_distance=0.5)
    assert truth.tolist() == [3, 8, -1, 100, 0]


# --- cross-weather separation (the invariance table) ----------------------------------------

def test_separation_of_a_single_query_with_a_true_place_is_computed():
    """Kills ``len(cols) == 1``: one query with a true place is enough."""
    from cmal_lcd.evaluation.invariance import cross_weather_separation

    D = np.array([[1.0, 9.0], [4.0, 9.0], [6.0, 9.0]])
    out = cross_weather_separation(D, np.array([0, -1]), d_thresh=0)
    assert out == {"same_place": 1.0, "other_place": 5.0, "ratio": 0.2,
                   "single_frame_recall_at_1": 1.0, "n_queries": 1}


def test_separation_without_a_true_place_names_every_statistic_as_nan():
    from cmal_lcd.evaluation.invariance import cross_weather_separation

    out = cross_weather_separation(np.ones((3, 2)), np.array([-1, -1]), d_thresh=0)
    assert set(out) == {"same_place", "other_place", "ratio", "single_frame_recall_at_1",
                        "n_queries"}
    assert out["n_queries"] == 0 and all(np.isnan(v) for k, v in out.items() if k != "n_queries")


@pytest.mark.parametrize("other, ratio", [(0.0, None), (0.5, 2.0), (1.0, 1.0)])
def test_the_separation_ratio_needs_a_positive_other_place_mean(other, ratio):
    """Kills ``>= 0`` (a division by zero) and ``> 1`` (ratios over means below 1 lost)."""
    from cmal_lcd.evaluation.invariance import cross_weather_separation

    D = np.array([[1.0], [other]])
    out = cross_weather_separation(D, np.array([0]), d_thresh=0)
    assert out["other_place"] == other
    assert (np.isnan(out["ratio"]) if ratio is None else out["ratio"] == ratio)


def test_separation_refuses_non_finite_differences_naming_d():
    from cmal_lcd.evaluation.invariance import cross_weather_separation

    with pytest.raises(ValueError, match="^D: expected finite differences$"):
        cross_weather_separation(np.array([[1.0, np.inf]]), np.array([0, 0]), d_thresh=0)


# --- recall@K input checks --------------------------------------------------------------------

@pytest.mark.parametrize("top_k", [np.zeros((3, 2), dtype=np.int64),      # one row too many
                                   np.zeros((2, 2), dtype=np.float64),    # not integers
                                   np.zeros(2, dtype=np.int64)])          # not (Q, K)
def test_recall_at_k_refuses_a_top_k_of_the_wrong_shape_or_type(top_k):
    """Each condition alone is refused (kills ``and`` for ``or`` in the check)."""
    from cmal_lcd.evaluation.metrics import recall_at_k

    with pytest.raises(ValueError, match=r"top_k must be an integer array of shape \(2, K\)"):
        recall_at_k(top_k, np.array([0, 1]), ks=(1,), d_thresh=0)


def test_recall_at_k_names_a_bad_queries_mask_and_an_empty_one():
    from cmal_lcd.evaluation.metrics import recall_at_k

    top_k = np.array([[0], [1]])
    with pytest.raises(ValueError, match=r"queries must have shape \(2,\), got \(3,\)"):
        recall_at_k(top_k, np.array([0, 1]), ks=(1,), d_thresh=0, queries=[True] * 3)
    with pytest.raises(ValueError, match="^queries: no query to count$"):
        recall_at_k(top_k, np.array([0, 1]), ks=(1,), d_thresh=0, queries=[False, False])
    with pytest.raises(ValueError, match=r"^truth must be a 1-D array, got shape \(1, 2\)$"):
        recall_at_k(top_k, np.array([[0, 1]]), ks=(1,), d_thresh=0)


# --- loop_closure_metrics: single-frame recall@K alone, and what each refusal says ---------

def test_single_frame_recall_at_k_is_reported_without_the_sequence_top_k():
    """Kills ``break`` for ``continue``: without ``top_k`` the single-frame recall@K still
    comes (hand-computed: query 0's true row 3 is its 2nd single-frame candidate)."""
    from cmal_lcd.evaluation.metrics import RECALL_KS, loop_closure_metrics

    match, confidence, truth = np.array([3, 1]), np.array([0.2, 0.4]), np.array([3, 1])
    ranked = np.array([[0] + [3] * (max(RECALL_KS) - 1), [1] * max(RECALL_KS)])
    out = loop_closure_metrics(match, confidence, truth, d_thresh=0,
                               single_frame_match=np.array([0, 1]),
                               single_frame_top_k=ranked)
    assert out["single_frame_recall_at_1"] == 0.5
    assert all(out[f"single_frame_recall_at_{k}"] == 1.0 for k in RECALL_KS if k != 1)
    assert not any(key.startswith("recall_at_") and key != "recall_at_1" and
                   key != "recall_at_100p" for key in out)


@pytest.mark.parametrize("match, confidence, truth, message", [
    ([-1, -1], [np.nan, np.nan], [0, 1], r"^match: no scored query \(every match is -1\): "
                                         r"a sequence needs at least ds \+ 1 query frames, .* "
                                         r"\(e\.g\. identical codes\) has no valid trajectory$"),
    ([0, 1], [0.1, np.nan], [0, 1], r"^confidence must be finite for every scored query "
                                   r"\(match >= 0\)$"),
    ([0, 1], [0.1, 0.2], [-1, -1], r"^truth: no scored query has its place in the reference "
                                   r"\(truth >= 0\), so recall is undefined$"),
    ([[0, 1]], [0.1, 0.2], [0, 1], r"^match must be a 1-D array"),
    ([0, 1], [0.1, 0.2], [[0, 1]], r"^truth must be a 1-D array"),
])
def test_loop_closure_metrics_refusals_name_what_is_wrong(match, confidence, truth, message):
    from cmal_lcd.evaluation.metrics import loop_closure_metrics

    with pytest.raises(ValueError, match=message):
        loop_closure_metrics(np.array(match), np.array(confidence), np.array(truth), d_thresh=0)


def test_a_single_frame_match_of_another_shape_is_named():
    from cmal_lcd.evaluation.metrics import loop_closure_metrics

    with pytest.raises(ValueError, match=r"^single_frame_match must have shape \(2,\), got "
                                         r"\(3,\)$"):
        loop_closure_metrics(np.array([0, 1]), np.array([0.1, 0.2]), np.array([0, 1]),
                             d_thresh=0, single_frame_match=np.array([0, 1, 2]))
    with pytest.raises(ValueError, match=r"^single_frame_match must be a 1-D array"):
        loop_closure_metrics(np.array([0, 1]), np.array([0.1, 0.2]), np.array([0, 1]),
                             d_thresh=0, single_frame_match=np.array([[0, 1]]))


@pytest.mark.parametrize("truth, which", [([0, 1], "all"), ([5, 7], "none")])
def test_an_undefined_auc_roc_says_whether_all_or_none_are_correct(truth, which, caplog):
    from cmal_lcd.evaluation.metrics import loop_closure_metrics

    with caplog.at_level("WARNING", logger="cmal_lcd.evaluation.metrics"):
        out = loop_closure_metrics(np.array([0, 1]), np.array([0.1, 0.2]), np.array(truth),
                                   d_thresh=0)
    assert np.isnan(out["auc_roc"])
    assert f"auc_roc is undefined (NaN): {which} of the 2 scored queries are correct" \
        in caplog.text


# --- the ground-truth run (2026-12-01): return types and the names in each refusal -----------
# A run over ground_truth.py alone (tests/evaluation) left 42 of 257 mutants alive; the ones
# below changed what a caller sees. The rest are chunk sizes (any size gives the same rows),
# fills that every row overwrites, and dtype arguments on inputs already of that type
# (docs/testing.md).

def test_every_ground_truth_is_an_int64_row_index_array():
    """Kills ``dtype=None`` (float rows) in each of the three ground truths."""
    xy = np.array([[0.0, 0.0], [10.0, 0.0], [0.0, 0.5], [10.0, 0.5]])
    by_index = ground_truth_from_correspondence(2, 3)
    by_pose = ground_truth_from_poses(xy[:2], xy[2:], max_distance=1.0)
    loops = loop_ground_truth_from_poses(xy, pose_tolerance=1.0, n_allowed=np.array([0, 0, 1, 2]))
    nearest = revisit_nearest_to(np.array([-1, -1, 0, 1]), xy, pose_tolerance=1.0,
                                 n_allowed=np.array([0, 0, 1, 2]))
    assert by_index.dtype == by_pose.dtype == loops.dtype == nearest.dtype == np.int64
    assert by_index.tolist() == [0, 1, -1]
    assert by_pose.tolist() == [0, 1]
    assert loops.tolist() == nearest.tolist() == [-1, -1, 0, 1]


@pytest.mark.parametrize("reference, query, message", [
    (np.zeros((0, 2)), np.zeros((2, 2)), r"^reference_xy is empty$"),
    (np.zeros((2, 2)), np.zeros((0, 2)), r"^query_xy is empty$"),
    (np.zeros((2, 3)), np.zeros((2, 2)), r"^reference_xy must be an \(N, 2\) array"),
    (np.zeros((2, 2)), np.zeros(2), r"^query_xy must be an \(N, 2\) array"),
])
def test_pose_ground_truth_refusals_name_the_drive(reference, query, message):
    """Kills the argument names in ``_check_xy``'s messages and ``shape[1] < 1`` for the empty
    check (an empty reference then failed inside ``argmin`` with numpy's message)."""
    with pytest.raises(ValueError, match=message):
        ground_truth_from_poses(reference, query, max_distance=1.0)


def test_revisit_refusals_name_xy_and_frames():
    allowed = np.zeros(3, int)
    with pytest.raises(ValueError, match=r"^xy must be an \(N, 2\) array"):
        revisit_nearest_to(None, np.zeros((3, 3)), pose_tolerance=1.0, n_allowed=allowed)
    with pytest.raises(ValueError, match=r"^xy is empty$"):
        revisit_nearest_to(None, np.zeros((0, 2)), pose_tolerance=1.0, n_allowed=allowed[:0])
    with pytest.raises(ValueError, match=r"^frames must have shape \(3,\), got \(2,\)$"):
        revisit_nearest_to(np.zeros(2, int), np.zeros((3, 2)), pose_tolerance=1.0,
                           n_allowed=allowed)


def test_the_monitor_scores_nothing_without_validation_pairs():
    """``score`` with codes but no validation pair returns no metric (not NaN means); the
    2026-12-01 evaluation/ run let ``and`` for ``or`` in its guard through."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from monitor_helpers import monitor_for, validation_drives

    images, frames, _ = validation_drives()
    monitor = monitor_for(images, frames, [])
    codes = images.reshape(len(images), -1).astype(np.float32)
    centring = monitor.centring_images.reshape(len(monitor.centring_images), -1)
    assert monitor.score(codes, centring.astype(np.float32)) == {}


def test_centring_means_are_read_only_for_condition_centring_and_per_condition(tmp_path):
    """``centring_means``: None for a protocol that does not centre on the condition (no file
    is read: the folder here is empty); else the training mean code of each label, for
    ``n_conditions`` conditions when given (each must have training frames), else 1 + the
    largest label. Hand-computed means."""
    from cmal_lcd.evaluation.protocol import MatchingProtocol
    from cmal_lcd.evaluation.protocol_file import centring_means
    from cmal_lcd.matching.normalise import CodeNormalisation

    empty = tmp_path / "empty"
    empty.mkdir()
    for centre in ("none", "reference"):
        protocol = MatchingProtocol(CodeNormalisation(centre, True), enhance=False, r_window=10)
        assert centring_means(protocol, empty) is None
    folder = tmp_path / "features"
    folder.mkdir()
    np.save(folder / "train_codes.npy", np.array([[0, 2], [2, 4], [10, 0], [12, 0], [5, 5],
                                                  [7, 7]], dtype=np.float32))
    np.save(folder / "train_labels.npy", np.array([0, 0, 1, 1, 2, 2], dtype=np.int64))
    condition = MatchingProtocol(CodeNormalisation("condition", True), enhance=False,
                                 r_window=10)
    np.testing.assert_allclose(centring_means(condition, folder), [[1, 3], [11, 0], [6, 6]])
    np.testing.assert_allclose(centring_means(condition, folder, 3), [[1, 3], [11, 0], [6, 6]])
    with pytest.raises(ValueError, match="condition 3 has no training frame"):
        centring_means(condition, folder, 4)  # the given count is used, not the labels'
