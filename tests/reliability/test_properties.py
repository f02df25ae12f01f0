"""Property-based tests (hypothesis) of the matching and metrics libraries.

For any finite input of a valid shape: no exception, results in their documented ranges,
invariance under a permutation of the query frames, a PR curve whose recall never decreases
as the threshold rises, and agreement with scikit-learn.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from sklearn.metrics import average_precision_score, roc_auc_score

from cmal_lcd.evaluation import (
    correct_matches,
    loop_closure_metrics,
    precision_recall_curve,
)
from cmal_lcd.matching import (
    SeqSLAMParams,
    difference_matrix,
    enhance_contrast,
    match_sequences,
    sad_thumbnails,
)

SETTINGS = settings(max_examples=60, deadline=None,
                    suppress_health_check=[HealthCheck.too_slow])
RATES = ("auc_pr", "auc_roc", "recall_at_100p", "recall_at_1", "single_frame_recall_at_1")


@st.composite
def loop_closure_inputs(draw):
    """match, confidence, truth, single-frame match of Q queries over R reference frames."""
    q = draw(st.integers(1, 40))
    r = draw(st.integers(1, 40))
    match = draw(hnp.arrays(np.int64, q, elements=st.integers(-1, r - 1)))
    truth = draw(hnp.arrays(np.int64, q, elements=st.integers(-1, r - 1)))
    # few distinct values, so ties are frequent
    confidence = draw(hnp.arrays(np.float64, q, elements=st.sampled_from(
        [0.0, 0.1, 0.25, 0.5, 0.5000001, 0.9, 1.0, 3.0])))
    single = draw(hnp.arrays(np.int64, q, elements=st.integers(-1, r - 1)))
    d_thresh = draw(st.integers(0, 3))
    scored = match >= 0
    assume(scored.any() and (truth[scored] >= 0).any())
    return match, confidence, truth, single, d_thresh


@SETTINGS
@given(loop_closure_inputs())
def test_metrics_are_rates_in_the_unit_interval_or_nan_roc(inputs):
    match, confidence, truth, single, d_thresh = inputs
    metrics = loop_closure_metrics(match, confidence, truth, d_thresh=d_thresh,
                                   single_frame_match=single)
    for key in RATES:
        value = metrics[key]
        if key == "auc_roc" and np.isnan(value):
            correct = correct_matches(match, truth, d_thresh=d_thresh)[match >= 0]
            assert correct.all() or not correct.any()  # undefined only with one class
            continue
        assert 0.0 <= value <= 1.0 + 1e-12, (key, value)
    correct = correct_matches(match, truth, d_thresh=d_thresh)[match >= 0]
    max_recall = correct.sum() / metrics["n_positive"]
    assert metrics["recall_at_100p"] <= max_recall + 1e-12
    assert metrics["auc_pr"] <= max_recall + 1e-12
    assert metrics["n_scored"] == int((match >= 0).sum())


@SETTINGS
@given(loop_closure_inputs(), st.randoms(use_true_random=False))
def test_metrics_do_not_depend_on_the_order_of_the_queries(inputs, rnd):
    match, confidence, truth, single, d_thresh = inputs
    order = np.array(rnd.sample(range(match.size), match.size), dtype=np.int64)
    a = loop_closure_metrics(match, confidence, truth, d_thresh=d_thresh,
                             single_frame_match=single)
    b = loop_closure_metrics(match[order], confidence[order], truth[order], d_thresh=d_thresh,
                             single_frame_match=single[order])
    for key in a:
        assert a[key] == pytest.approx(b[key], abs=1e-12, nan_ok=True), key


@SETTINGS
@given(loop_closure_inputs())
def test_pr_curve_recall_never_decreases_as_the_threshold_rises(inputs):
    match, confidence, truth, _, d_thresh = inputs
    scored = match >= 0
    correct = correct_matches(match, truth, d_thresh=d_thresh)[scored]
    n_positive = int((truth[scored] >= 0).sum())
    precision, recall, thresholds = precision_recall_curve(confidence[scored], correct,
                                                           n_positive=n_positive)
    assert np.all(np.diff(thresholds) > 0)
    assert np.all(np.diff(recall) >= 0)
    assert np.all((precision >= 0) & (precision <= 1)) and np.all((recall >= 0) & (recall <= 1))
    assert recall[-1] == pytest.approx(correct.sum() / n_positive)


@SETTINGS
@given(loop_closure_inputs())
def test_metrics_agree_with_scikit_learn(inputs):
    match, confidence, truth, _, d_thresh = inputs
    metrics = loop_closure_metrics(match, confidence, truth, d_thresh=d_thresh)
    scored = match >= 0
    correct = correct_matches(match, truth, d_thresh=d_thresh)[scored]
    n_positive = int((truth[scored] >= 0).sum())
    score = -confidence[scored]
    if correct.any() and not correct.all():
        assert metrics["auc_roc"] == pytest.approx(roc_auc_score(correct, score), abs=1e-12)
    if correct.any():
        expected = average_precision_score(correct, score) * correct.sum() / n_positive
        assert metrics["auc_pr"] == pytest.approx(expected, abs=1e-12)
    else:
        assert metrics["auc_pr"] == 0.0 and metrics["recall_at_100p"] == 0.0


# ------------------------------------------------------------------------------- matching

finite32 = st.floats(-1e3, 1e3, allow_nan=False, allow_infinity=False, width=32)


@st.composite
def feature_pair(draw, *, dtype=np.float32, elements=finite32):
    f = draw(st.integers(1, 6))
    r = draw(st.integers(1, 30))
    q = draw(st.integers(1, 30))
    reference = draw(hnp.arrays(dtype, (r, f), elements=elements))
    query = draw(hnp.arrays(dtype, (q, f), elements=elements))
    return reference, query


@st.composite
def seqslam_params(draw):
    v_min = draw(st.sampled_from([0.5, 0.8, 1.0]))
    return SeqSLAMParams.defaults(ds=draw(st.integers(1, 6)), v_min=v_min,
                         v_max=v_min + draw(st.sampled_from([0.0, 0.3, 0.6])),
                         v_step=draw(st.sampled_from([0.1, 0.25])),
                         r_window=draw(st.sampled_from([0, 2, 3, 6])),
                         enhance=draw(st.booleans()),
                         score=draw(st.sampled_from(["ratio", "sum"])))


@SETTINGS
@given(feature_pair(), seqslam_params(), st.sampled_from(["sad", "sqeuclidean"]))
def test_matching_any_finite_input_gives_results_in_range(pair, params, metric):
    reference, query = pair
    result = match_sequences(reference, query, metric=metric, params=params)
    R, Q = len(reference), len(query)
    for name in ("match", "single_frame_match"):
        values = getattr(result, name)
        assert values.shape == (Q,) and values.dtype == np.int64
        assert np.all((values >= -1) & (values < R))
    scored = result.match >= 0
    assert not scored[:params.ds].any()  # too little history
    assert np.isfinite(result.score[scored]).all()
    assert np.all((result.ratio[scored] >= 0) & (result.ratio[scored] <= 1))
    assert np.isnan(result.ratio[~scored]).all() and np.isnan(result.score[~scored]).all()


@SETTINGS
@given(feature_pair(), st.sampled_from(["sad", "sqeuclidean"]), st.randoms(use_true_random=False))
def test_difference_matrix_is_non_negative_and_permutes_with_the_queries(pair, metric, rnd):
    reference, query = pair
    D = difference_matrix(reference, query, metric=metric)
    assert D.shape == (len(reference), len(query)) and D.dtype == np.float32
    assert np.all(D >= 0) and np.isfinite(D).all()
    order = np.array(rnd.sample(range(len(query)), len(query)), dtype=np.int64)
    np.testing.assert_array_equal(difference_matrix(reference, query[order], metric=metric),
                                  D[:, order])


@SETTINGS
@given(feature_pair(elements=st.floats(-100, 100, width=32)))
def test_difference_matrix_agrees_with_a_float64_reference(pair):
    reference, query = pair
    ref64, qry64 = reference.astype(np.float64), query.astype(np.float64)
    sad = np.abs(ref64[:, None, :] - qry64[None, :, :]).mean(axis=2)
    sq = ((ref64[:, None, :] - qry64[None, :, :]) ** 2).sum(axis=2)
    np.testing.assert_allclose(difference_matrix(reference, query, metric="sad"), sad,
                               rtol=1e-5, atol=1e-4)
    np.testing.assert_allclose(difference_matrix(reference, query, metric="sqeuclidean"), sq,
                               rtol=1e-5, atol=1e-2)


@SETTINGS
@given(hnp.arrays(np.float32, st.tuples(st.integers(1, 25), st.integers(1, 8)),
                  elements=st.floats(0, 1e3, width=32)),
       st.sampled_from([0, 2, 3, 5, 10]))
def test_enhancement_never_produces_nan(D, r_window):
    out = enhance_contrast(D, r_window=r_window)
    assert out.shape == D.shape and out.dtype == np.float32
    assert not np.isnan(out).any()


@SETTINGS
@given(hnp.arrays(np.uint8, st.tuples(st.integers(1, 4), st.integers(8, 24), st.integers(8, 24),
                                       st.just(3))),
       st.sampled_from([0, 2, 4]))
def test_sad_thumbnails_of_any_image_are_finite(images, patch):
    thumbs = sad_thumbnails(images, width=8, height=4, patch=patch)
    assert thumbs.shape == (len(images), 32) and thumbs.dtype == np.float32
    assert np.isfinite(thumbs).all()
