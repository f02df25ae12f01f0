"""Ground truth as sets of right reference rows (ReferenceSets) and the metrics over them."""

import numpy as np
import pytest
import scipy.sparse

from cmal_lcd.evaluation import loop_closure_metrics, recall_at_k
from cmal_lcd.data.ground_truth import ReferenceSets
from cmal_lcd.evaluation.metrics import correct_matches, scored_and_correct


def _sets():
    # 4 references x 3 queries: q0 -> {0, 1}, q1 -> {} (no place), q2 -> {3}, soft-only (2, q2)
    return ReferenceSets.from_lists([[0, 1], [], [3]], n_reference=4,
                                    ignored_lists=[[1], [], [2, 3]], source="test",
                                    tolerance="as listed")


def test_membership_and_places():
    sets = _sets()
    assert sets.is_right(np.array([1, 0, 3])).tolist() == [True, False, True]
    assert sets.is_right(np.array([-1, 2, 2])).tolist() == [False, False, False]
    # (2, q2) is soft only; (1, q0) is in both lists, so right, not ignored
    assert sets.is_ignored(np.array([1, 0, 2])).tolist() == [False, False, True]
    assert sets.has_place().tolist() == [True, False, True]
    assert sets.right_rows(0).tolist() == [0, 1] and sets.right_rows(1).tolist() == []
    assert sets.nearest_right(np.array([3, 0, -1])).tolist() == [1, -1, 3]
    assert sets.describe() == {"source": "test", "tolerance": "as listed",
                               "n_right_pairs": 3, "n_ignored_pairs": 1}


def test_matrices_dense_and_sparse_agree():
    rng = np.random.default_rng(0)
    hard = rng.random((30, 20)) < 0.1
    soft = hard | (rng.random((30, 20)) < 0.1)
    dense = ReferenceSets.from_matrices(hard, soft)
    sparse = ReferenceSets.from_matrices(scipy.sparse.csr_matrix(hard),
                                         scipy.sparse.csc_matrix(soft))
    rows = rng.integers(0, 30, size=(20, 5))
    expected_right = hard[rows, np.arange(20)[:, None]]
    expected_ignored = (soft & ~hard)[rows, np.arange(20)[:, None]]
    for sets in (dense, sparse):
        assert (sets.n_reference, sets.n_query) == (30, 20)
        assert np.array_equal(sets.is_right(rows), expected_right)
        assert np.array_equal(sets.is_ignored(rows), expected_ignored)


def test_from_truth_matches_index_tolerance():
    truth = np.array([5, -1, 0, 9])
    sets = ReferenceSets.from_truth(truth, d_thresh=2, n_reference=10)
    match = np.array([7, 3, 2, 6])
    assert np.array_equal(sets.is_right(match), correct_matches(match, truth, d_thresh=2))
    assert sets.tolerance == "2 frames"


@pytest.mark.parametrize("kwargs, message", [
    ({"right": np.array([[4, 0]])}, "reference index 4 outside 0..3"),
    ({"right": np.array([[0, 3]])}, "query index 3 outside 0..2"),
    ({"right": np.array([0, 1])}, "expected integer (M, 2) pairs"),
])
def test_bad_pairs_are_named(kwargs, message):
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(")", r"\)")):
        ReferenceSets(n_reference=4, n_query=3, **kwargs)


def test_index_truth_and_its_sets_give_the_same_metrics():
    rng = np.random.default_rng(1)
    n_ref, n_q = 60, 40
    truth = np.where(rng.random(n_q) < 0.8, rng.integers(0, n_ref, n_q), -1)
    match = np.clip(truth + rng.integers(-4, 5, n_q), 0, n_ref - 1)
    match[truth < 0] = rng.integers(0, n_ref, int(np.sum(truth < 0)))
    confidence = rng.random(n_q)
    top_k = np.column_stack([match, rng.integers(0, n_ref, (n_q, 19))])
    by_index = loop_closure_metrics(match, confidence, truth, d_thresh=2, top_k=top_k)
    by_sets = loop_closure_metrics(match, confidence,
                                   ReferenceSets.from_truth(truth, d_thresh=2, n_reference=n_ref),
                                   d_thresh=2, top_k=top_k)
    assert by_sets == pytest.approx(by_index, nan_ok=True)


def test_a_match_on_an_ignored_row_is_left_out():
    sets = _sets()
    match, confidence = np.array([0, 0, 2]), np.array([0.1, 0.2, 0.3])
    scored, correct, n_positive = scored_and_correct(match, confidence, sets, d_thresh=0)
    assert scored.tolist() == [True, True, False]
    assert correct.tolist() == [True, False, False] and n_positive == 1
    metrics = loop_closure_metrics(match, confidence, sets, d_thresh=0)
    assert metrics["n_scored"] == 2 and metrics["recall_at_1"] == 0.5
    assert metrics["recall_at_100p"] == 1.0


def test_ranked_recall_skips_ignored_rows():
    sets = ReferenceSets.from_lists([[3], [0]], n_reference=4, ignored_lists=[[1, 2], []])
    # q0: ranked 1 (ignored), 2 (ignored), 3 (right) -> a hit at rank 1 once they step aside
    top_k = np.array([[1, 2, 3], [2, 1, 0]])
    assert recall_at_k(top_k, sets, d_thresh=0, ks=(1, 2, 3)) == {1: 0.5, 2: 0.5, 3: 1.0}


def test_subset_renumbers_and_drops_pairs_outside():
    rng = np.random.default_rng(4)
    hard = rng.random((12, 9)) < 0.3
    soft = hard | (rng.random((12, 9)) < 0.2)
    sets = ReferenceSets.from_matrices(hard, soft, source="s", tolerance="t")
    ref_rows, query_rows = np.array([1, 2, 5, 8, 11]), np.array([0, 3, 4, 8])
    sub = sets.subset(ref_rows, query_rows)
    assert (sub.n_reference, sub.n_query, sub.source, sub.tolerance) == (5, 4, "s", "t")
    every = np.tile(np.arange(5), (4, 1))
    assert np.array_equal(sub.is_right(every), hard[np.ix_(ref_rows, query_rows)].T)
    assert np.array_equal(sub.is_ignored(every),
                          (soft & ~hard)[np.ix_(ref_rows, query_rows)].T)
    with pytest.raises(ValueError, match="query_rows: expected strictly increasing"):
        sets.subset(ref_rows, np.array([3, 3]))


def test_arrays_round_trip():
    sets = _sets()
    back = ReferenceSets.from_arrays(sets.to_arrays(), source="test", tolerance="as listed")
    every = np.tile(np.arange(4), (3, 1))
    assert np.array_equal(back.is_right(every), sets.is_right(every))
    assert np.array_equal(back.is_ignored(every), sets.is_ignored(every))
    assert back.describe() == sets.describe()
