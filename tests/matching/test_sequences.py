"""SeqSLAM over sides that hold several sequences (Mapillary SLS): nothing crosses a boundary.

The streamed implementation must equal the plain-loop reference (``seqslam_loops``, which reads
the sequence rules straight from their definitions) on every query.
"""

import numpy as np
import pytest
from seqslam_loops import loop_enhance, loop_row_scores, loop_search, loop_single_frame
from test_seqslam import TOL, assert_same_matches, route_features

from cmal_lcd.matching import SeqSLAMParams, SequenceBlocks, match_sequences

REFERENCE_LABELS = np.array(["a"] * 9 + ["b"] * 7 + ["c"] * 12)  # 28 rows, three drives
QUERY_LABELS = np.array([5] * 8 + [2] * 11)  # 19 queries, two drives


@pytest.mark.parametrize("metric", ["sad", "sqeuclidean"])
@pytest.mark.parametrize("params", [SeqSLAMParams.defaults(ds=4, r_window=6),
                                    SeqSLAMParams.defaults(ds=3, r_window=4, enhance=False),
                                    SeqSLAMParams.defaults(ds=5, v_min=0.5, v_max=1.5, v_step=0.5,
                                                  r_window=8, score="sum")])
@pytest.mark.parametrize("chunk_size", [3, 1000])
def test_matching_over_several_sequences_equals_the_loop_pipeline(metric, params, chunk_size):
    reference, query = route_features(28, 19, shift=3)
    result = match_sequences(reference, query, metric=metric, params=params, keep_matrices=True,
                             chunk_size=chunk_size, reference_sequences=REFERENCE_LABELS,
                             query_sequences=QUERY_LABELS)
    D_hat = (loop_enhance(result.D, r_window=params.r_window,
                          reference_sequences=REFERENCE_LABELS) if params.enhance
             else result.D.astype(np.float64))
    expected = loop_search(D_hat, ds=params.ds, velocities=list(params.velocities()),
                           r_window=params.r_window, reference_sequences=REFERENCE_LABELS,
                           query_sequences=QUERY_LABELS)
    assert_same_matches(result, expected)
    sf_match, sf_ratio = loop_single_frame(result.D, r_window=params.r_window,
                                           reference_sequences=REFERENCE_LABELS)
    np.testing.assert_array_equal(result.single_frame_match, sf_match)
    np.testing.assert_allclose(result.single_frame_ratio, sf_ratio, **TOL)
    if params.enhance:  # the stored D_hat is the per-sequence enhancement
        np.testing.assert_allclose(result.D_hat, D_hat, rtol=1e-5, atol=1e-5)


def test_top_k_lists_rank_only_trajectories_inside_one_reference_sequence():
    reference, query = route_features(28, 19, shift=3)
    params = SeqSLAMParams.defaults(ds=4, r_window=6, enhance=False)
    result = match_sequences(reference, query, metric="sqeuclidean", params=params, top_k=6,
                             keep_matrices=True, reference_sequences=REFERENCE_LABELS,
                             query_sequences=QUERY_LABELS)
    bounds = [(int(lo), int(hi)) for lo, hi in
              zip(*vars(SequenceBlocks.from_labels(REFERENCE_LABELS, n=28, name="x")).values())]
    for T in np.flatnonzero(result.match >= 0):
        per_row = np.array(loop_row_scores(result.D.astype(np.float64), T, ds=4,
                                           velocities=list(params.velocities()),
                                           bounds=bounds))
        order = np.argsort(per_row, kind="stable")[:6]
        expected = np.where(np.isfinite(per_row[order]), order, -1)
        np.testing.assert_array_equal(result.sequence_top_k[T], expected)
    unscored = result.match < 0
    assert (result.sequence_top_k[unscored] == -1).all()
    assert np.isnan(result.sequence_top_k_score[unscored]).all()


def test_a_reference_sequence_shorter_than_the_look_back_is_never_matched():
    """Its frames are an exact copy of the query, and still no trajectory fits inside it."""
    reference, query = route_features(40, 30, shift=5)
    reference[20:26] = query[20:26]  # a 6-frame drive of its own, identical to the query
    labels = np.array([0] * 20 + [1] * 6 + [2] * 14)
    result = match_sequences(reference, query, metric="sqeuclidean",
                             params=SeqSLAMParams.defaults(ds=10), reference_sequences=labels)
    assert result.n_scored > 0
    assert not np.isin(result.match, np.arange(20, 26)).any()
    assert np.isin(result.single_frame_match, np.arange(20, 26)).any()  # no look-back there


def test_queries_are_scored_only_with_ds_earlier_queries_of_their_own_sequence():
    reference, query = route_features(50, 30, shift=5)
    labels = np.array(["x"] * 12 + ["y"] * 5 + ["z"] * 13)
    result = match_sequences(reference, query, metric="sad", params=SeqSLAMParams.defaults(ds=4),
                             query_sequences=labels)
    scored = np.flatnonzero(result.match >= 0)
    expected = np.r_[np.arange(4, 12), np.arange(16, 17), np.arange(21, 30)]
    np.testing.assert_array_equal(scored, expected)
    assert (result.single_frame_match >= 0).all()


def test_one_label_everywhere_is_the_plain_run_bit_for_bit():
    reference, query = route_features(40, 31, shift=5)
    plain = match_sequences(reference, query, metric="sad", top_k=5)
    labelled = match_sequences(reference, query, metric="sad", top_k=5,
                               reference_sequences=np.zeros(40), query_sequences=["q"] * 31)
    for field in ("match", "score", "ratio", "single_frame_match", "single_frame_ratio",
                  "sequence_top_k", "sequence_top_k_score"):
        np.testing.assert_array_equal(getattr(labelled, field), getattr(plain, field), field)


@pytest.mark.parametrize("labels, message", [
    (["a"] * 5 + ["b"] * 5 + ["a"] * 10, "sequence 'a' comes back at frame 10"),
    (["a"] * 19, r"one sequence label per frame \(20\)"),
])
def test_bad_sequence_labels_are_refused_naming_the_side(labels, message):
    reference, query = route_features(20, 15)
    with pytest.raises(ValueError, match=f"reference_sequences.*{message}"):
        match_sequences(reference, query, metric="sad", reference_sequences=labels)


def test_blocks_give_each_frame_the_bounds_of_its_sequence():
    blocks = SequenceBlocks.from_labels([7, 7, 3, 3, 3, 9], n=6, name="labels")
    np.testing.assert_array_equal(blocks.lo, [0, 0, 2, 2, 2, 5])
    np.testing.assert_array_equal(blocks.hi, [1, 1, 4, 4, 4, 5])
    assert blocks.count == 3
