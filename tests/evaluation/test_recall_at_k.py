"""recall@K (K = 1, 5, 10, 20), single-frame and after sequence matching, against plain loops.

A query is correct at K when one of its K best reference rows lies within ``d_thresh`` frames
of its true place; the share is over the scored queries (as recall@1). The loops below rank the
reference rows from the definitions (sort by value, ties by the lower row), with no vectorisation.
"""

import math
import sys
from pathlib import Path

import numpy as np
import pytest

from cmal_lcd.evaluation import (RECALL_AT_K_KEYS, RECALL_KS, loop_closure_metrics,
                                 recall_at_k)
from cmal_lcd.evaluation.loop_closure import evaluate_pair
from cmal_lcd.matching import SeqSLAMParams, match_sequences

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "matching"))
from seqslam_loops import loop_enhance  # noqa: E402


def loop_rank_lists(columns, k):
    """Per query, the first ``k`` rows by (value, row) ascending; ``-1`` for +inf and beyond R."""
    lists = []
    for column in columns:
        ranked = sorted(range(len(column)), key=lambda r: (column[r], r))
        row = [r if math.isfinite(column[r]) else -1 for r in ranked[:k]]
        lists.append(row + [-1] * (k - len(row)))
    return np.array(lists, dtype=np.int64)


def loop_sequence_scores(D_hat, *, ds, offsets):
    """Per query T >= ds and end row s, the best sum over velocities (inf when invalid)."""
    R, Q = D_hat.shape
    columns = [[math.inf] * R for _ in range(Q)]
    for T in range(ds, Q):
        for s in range(R):
            for v in range(offsets.shape[0]):
                total = 0.0
                for j in range(ds, -1, -1):
                    k = s - int(offsets[v, j])
                    if k < 0:
                        total = math.inf
                        break
                    total += float(D_hat[k, T - j])
                columns[T][s] = min(columns[T][s], total)
    return columns


def loop_recall(lists, truth, scored, *, K, d_thresh):
    hits = 0
    for q in range(len(truth)):
        if not scored[q]:
            continue
        if truth[q] >= 0 and any(r >= 0 and abs(r - truth[q]) <= d_thresh for r in lists[q][:K]):
            hits += 1
    return hits / int(np.sum(scored))


def route(n_ref, n_query, *, shift, noise, seed, dim=8):
    rng = np.random.default_rng(seed)
    world = np.cumsum(rng.normal(size=(n_ref + n_query + shift, dim)), axis=0)
    query = world[shift:shift + n_query] + noise * rng.normal(size=(n_query, dim))
    return world[:n_ref].astype(np.float32), query.astype(np.float32)


# ---------------------------------------------------------------------------- recall_at_k


def test_hand_computed_lists():
    top = np.array([[7, 3, 5],     # truth 5: correct at rank 2 (K >= 3)
                    [4, -1, -1],   # truth 4: correct at rank 0
                    [1, 2, 3],     # truth -1 (place absent): never correct
                    [9, 8, 6]])    # truth 0: never within d_thresh = 1
    truth = np.array([5, 4, -1, 0])
    assert recall_at_k(top, truth, d_thresh=1, ks=(1, 2, 3)) == {1: 0.25, 2: 0.25, 3: 0.5}
    # d_thresh widens "correct": 7 is within 2 of 5
    assert recall_at_k(top, truth, d_thresh=2, ks=(1,)) == {1: 0.5}
    # the denominator is the counted queries only
    assert recall_at_k(top, truth, d_thresh=1, ks=(3,),
                       queries=np.array([True, True, False, False])) == {3: 1.0}


def test_recall_at_k_rejects_a_k_beyond_the_lists_and_no_counted_query():
    top = np.zeros((2, 5), dtype=np.int64)
    with pytest.raises(ValueError, match="ks"):
        recall_at_k(top, np.zeros(2, dtype=int), d_thresh=0, ks=(10,))
    with pytest.raises(ValueError, match="no query"):
        recall_at_k(top, np.zeros(2, dtype=int), d_thresh=0, ks=(1,),
                    queries=np.zeros(2, dtype=bool))


# ---------------------------------------------------------------- ranked lists vs the loops


@pytest.mark.parametrize("enhance", [True, False])
@pytest.mark.parametrize("chunk_size", [None, 7])
def test_ranked_lists_equal_the_loop(enhance, chunk_size):
    reference, query = route(45, 30, shift=4, noise=0.8, seed=3)
    params = SeqSLAMParams.defaults(ds=4, r_window=6, enhance=enhance)
    result = match_sequences(reference, query, metric="sad", params=params, top_k=20,
                             keep_matrices=True, chunk_size=chunk_size)
    assert result.sequence_top_k.shape == result.single_frame_top_k.shape == (30, 20)
    D = result.D.astype(np.float64)
    np.testing.assert_array_equal(result.single_frame_top_k,
                                  loop_rank_lists(D.T.tolist(), 20))
    D_hat = loop_enhance(D, r_window=6) if enhance else D
    scores = loop_sequence_scores(D_hat, ds=4, offsets=params.offsets())
    expected = loop_rank_lists(scores, 20)
    expected[result.match < 0] = -1
    np.testing.assert_array_equal(result.sequence_top_k, expected)


def test_lists_start_with_the_match_and_other_outputs_do_not_change():
    reference, query = route(120, 90, shift=10, noise=0.5, seed=1)
    plain = match_sequences(reference, query, metric="sad")
    ranked = match_sequences(reference, query, metric="sad", top_k=20)
    assert plain.sequence_top_k is None and plain.single_frame_top_k is None
    for name in ("match", "score", "ratio", "single_frame_match", "single_frame_ratio"):
        np.testing.assert_array_equal(getattr(ranked, name), getattr(plain, name))
    scored = plain.match >= 0
    np.testing.assert_array_equal(ranked.sequence_top_k[scored, 0], plain.match[scored])
    assert (ranked.sequence_top_k[~scored] == -1).all()
    np.testing.assert_array_equal(ranked.single_frame_top_k[:, 0], plain.single_frame_match)


def test_lists_longer_than_the_reference_end_with_minus_one():
    reference, query = route(8, 15, shift=0, noise=0.1, seed=2)
    result = match_sequences(reference, query, metric="sad", params=SeqSLAMParams.defaults(ds=3),
                             top_k=10)
    assert (result.single_frame_top_k[:, 8:] == -1).all()
    assert sorted(result.single_frame_top_k[0, :8]) == list(range(8))


def test_top_k_must_be_a_non_negative_integer():
    reference, query = route(20, 15, shift=0, noise=0.1, seed=0)
    with pytest.raises(ValueError, match="top_k"):
        match_sequences(reference, query, metric="sad", top_k=-1)


# --------------------------------------------------------------------- the metrics dict


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_loop_closure_metrics_recall_at_k_equals_the_loop(seed):
    reference, query = route(150, 110, shift=12, noise=1.5, seed=seed)
    result = match_sequences(reference, query, metric="sad", params=SeqSLAMParams.defaults(ds=5),
                             top_k=20)
    truth = np.arange(110) + 12
    truth[truth >= 150] = -1
    truth[40:50] = -1  # places absent from the reference
    d_thresh = 2
    metrics = loop_closure_metrics(result.match, result.confidence_score, truth,
                                   d_thresh=d_thresh,
                                   single_frame_match=result.single_frame_match,
                                   top_k=result.sequence_top_k,
                                   single_frame_top_k=result.single_frame_top_k)
    scored = result.match >= 0
    for K in RECALL_KS:
        seq = loop_recall(result.sequence_top_k.tolist(), truth, scored, K=K, d_thresh=d_thresh)
        sf = loop_recall(result.single_frame_top_k.tolist(), truth, scored, K=K,
                         d_thresh=d_thresh)
        suffix = f"recall_at_{K}"
        assert metrics[suffix] == pytest.approx(seq, abs=1e-12)
        assert metrics[f"single_frame_{suffix}"] == pytest.approx(sf, abs=1e-12)
    values = [metrics[f"recall_at_{K}"] for K in RECALL_KS]
    assert values == sorted(values)
    assert set(RECALL_AT_K_KEYS) <= set(metrics)


def test_recall_at_k_keys_only_with_ranked_lists_and_other_numbers_unchanged():
    reference, query = route(100, 80, shift=5, noise=3.0, seed=4)
    result = match_sequences(reference, query, metric="sad", top_k=20)
    truth = np.arange(80) + 5
    truth[30:40] = -1  # wrong matches exist, so every number is defined
    args = (result.match, result.confidence_score, truth)
    plain = loop_closure_metrics(*args, d_thresh=20, single_frame_match=result.single_frame_match)
    ranked = loop_closure_metrics(*args, d_thresh=20, single_frame_match=result.single_frame_match,
                                  top_k=result.sequence_top_k,
                                  single_frame_top_k=result.single_frame_top_k)
    assert not set(RECALL_AT_K_KEYS) & set(plain)
    assert {k: v for k, v in ranked.items() if k not in RECALL_AT_K_KEYS} == plain


def test_evaluate_pair_reports_recall_at_k():
    reference, query = route(100, 80, shift=5, noise=1.0, seed=5)
    truth = np.arange(80) + 5
    evaluation = evaluate_pair(reference, query, truth, metric="sad", params=SeqSLAMParams.defaults(),
                               d_thresh=3)
    assert set(RECALL_AT_K_KEYS) <= set(evaluation.metrics)
    assert 0.0 <= evaluation.metrics["recall_at_1"] <= evaluation.metrics["recall_at_20"] <= 1.0
