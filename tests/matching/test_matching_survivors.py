"""Specifications that the first mutation run over ``matching/`` showed were missing.

Each test states behaviour a user relies on; the docstring names the kind of mutant it kills
(``docs/testing.md``, "Mutation testing"). Expected values are computed here by brute force,
never by the function under test.
"""

import inspect

import numpy as np
import pytest
from seqslam_loops import loop_enhance, loop_search

from cmal_lcd.matching import difference as difference_module
from cmal_lcd.matching import SeqSLAMParams, difference_matrix
from cmal_lcd.matching.loops import exclusion_limits, travelled_distance
from cmal_lcd.matching.normalise import (CodeNormalisation, centring_sample, condition_means,
                                         l2_normalise, nearest_condition, normalise_pair)
from cmal_lcd.matching.params import matching_defaults, trajectory_velocities
from cmal_lcd.matching.sad import sad_thumbnails, thumbnail_options
from cmal_lcd.matching.seqslam import (enhance_contrast, match_sequences, sequence_search,
                                       single_frame_matches)


def test_nearest_condition_is_the_euclidean_argmin_even_when_means_are_close():
    """Kills a wrong coefficient in the expanded distance (``-3 c.m`` for ``-2 c.m``)."""
    rng = np.random.default_rng(3)
    means = rng.normal(size=(4, 6)) * 0.5
    codes = rng.normal(size=(200, 6))
    brute = np.argmin(((codes[:, None, :] - means[None, :, :]) ** 2).sum(-1), axis=1)
    np.testing.assert_array_equal(nearest_condition(codes, means), brute)


def test_l2_normalise_scales_short_rows_up_and_returns_float32():
    """Kills ``where=norm > 1`` (rows shorter than 1 left unscaled) and a dropped cast."""
    out = l2_normalise(np.array([[0.03, 0.04], [3.0, 4.0], [0.0, 0.0]]))
    assert out.dtype == np.float32
    np.testing.assert_allclose(out, [[0.6, 0.8], [0.6, 0.8], [0.0, 0.0]], rtol=1e-6)


@pytest.mark.parametrize("norm", [CodeNormalisation("reference"),
                                  CodeNormalisation("condition"),
                                  CodeNormalisation("reference", l2=True)],
                         ids=lambda n: n.label)
def test_normalised_codes_are_float32(norm):
    rng = np.random.default_rng(0)
    reference, query = rng.normal(size=(5, 3)), rng.normal(size=(4, 3))
    ref, qry = normalise_pair(reference, query, norm, train_means=np.zeros((2, 3)))
    assert ref.dtype == np.float32 and qry.dtype == np.float32


def test_condition_centring_refuses_means_of_the_wrong_width_naming_the_shape():
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match=r"train_means: expected \(K, 3\)"):
        normalise_pair(rng.normal(size=(5, 3)), rng.normal(size=(4, 3)),
                       CodeNormalisation("condition"), train_means=np.zeros((2, 4)))


def test_the_centring_sample_keeps_a_condition_with_one_frame_and_those_after_a_missing_one():
    """Kills ``len(own) == 1`` for ``== 0`` and ``break`` for ``continue``."""
    rows, labels = centring_sample(["a", "absent", "b", "c"], ["b", "a", "c", "c", "b"],
                                   per_condition=2)
    np.testing.assert_array_equal(rows, [0, 1, 2, 3, 4])
    np.testing.assert_array_equal(labels, [2, 0, 3, 3, 2])


def test_the_centring_sample_of_no_matching_frame_is_empty_int64():
    rows, labels = centring_sample(["a"], ["b", "b"], per_condition=3)
    assert rows.shape == labels.shape == (0,)
    assert rows.dtype == labels.dtype == np.int64


def test_condition_means_refuse_labels_of_the_wrong_length():
    """Kills ``and`` for ``or`` in the shape check (2-D codes, too few labels)."""
    with pytest.raises(ValueError, match="codes/labels"):
        condition_means(np.ones((4, 2)), np.array([0, 1, 1]), 2)


def test_matching_defaults_are_an_independent_copy_every_call():
    """Kills a shallow copy: a caller editing a nested node must not change the next call."""
    first = matching_defaults()
    first["sad"]["width"] = -1
    assert matching_defaults()["sad"]["width"] != -1


def _default(function, name):
    return inspect.signature(function).parameters[name].default


def test_the_public_functions_default_to_table_i():
    """Kills changed keyword defaults: a caller who passes nothing gets the config's Table I."""
    table_i = matching_defaults()
    assert _default(enhance_contrast, "r_window") == table_i["r_window"]
    assert _default(single_frame_matches, "r_window") == table_i["r_window"]
    for key in ("ds", "v_min", "v_max", "v_step", "r_window"):
        assert _default(sequence_search, key) == table_i[key], key


def test_enhance_contrast_with_its_default_window_equals_the_explicit_table_i_window():
    D = np.random.default_rng(1).random((40, 12)).astype(np.float32)
    np.testing.assert_array_equal(enhance_contrast(D),
                                  enhance_contrast(D, r_window=matching_defaults()["r_window"]))


def test_sequence_search_with_its_defaults_equals_the_explicit_table_i_search():
    """The behavioural twin of the signature check above (mutmut's trampolines show the
    original signature to ``inspect``, so only a call sees a mutated default)."""
    table_i = matching_defaults()
    D_hat = np.random.default_rng(2).random((60, 40))
    default = sequence_search(D_hat)
    explicit = sequence_search(D_hat, **{k: table_i[k] for k in
                                         ("ds", "v_min", "v_max", "v_step", "r_window")})
    np.testing.assert_array_equal(default.match, explicit.match)
    np.testing.assert_array_equal(default.score, explicit.score)


def test_enhance_contrast_refuses_an_infinite_difference():
    """Kills ``allow_inf=True``: a raw difference matrix is finite."""
    D = np.ones((5, 4), np.float32)
    D[2, 1] = np.inf
    with pytest.raises(ValueError, match="D"):
        enhance_contrast(D, r_window=2)


@pytest.mark.parametrize("metric", ["sad", "sqeuclidean"])
def test_difference_matrix_in_many_small_chunks_equals_brute_force(monkeypatch, metric):
    """Kills chunking over the wrong axis: more queries than features, a chunk of 3 queries."""
    monkeypatch.setattr(difference_module, "CHUNK_BYTES", 3 * 8 * 7)  # 3 queries of R=7
    rng = np.random.default_rng(2)
    reference, query = rng.normal(size=(7, 4)), rng.normal(size=(20, 4))
    diff = reference[:, None, :] - query[None, :, :]
    expected = np.abs(diff).mean(-1) if metric == "sad" else (diff ** 2).sum(-1)
    np.testing.assert_allclose(difference_matrix(reference, query, metric=metric), expected,
                               rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("xy", [np.zeros((4, 3)), np.array([[0.0, 0.0], [np.nan, 1.0]])],
                         ids=["three columns", "nan"])
def test_travelled_distance_refuses_positions_that_are_not_finite_xy(xy):
    """Kills ``and`` for ``or`` in the input check."""
    with pytest.raises(ValueError, match=r"finite \(N, 2\)"):
        travelled_distance(xy)


# --- SAD thumbnails: sizes, boundaries, empty input -------------------------------------------


def _frames(n=3, h=16, w=24, seed=0):
    return np.random.default_rng(seed).integers(0, 256, (n, h, w, 3), np.uint8)


@pytest.mark.parametrize("given", [("width",), ("height",), ("patch",), ("width", "height"),
                                   ("width", "patch"), ("height", "patch")], ids="+".join)
def test_sad_thumbnails_fill_each_size_left_out_from_the_config(given):
    """Kills ``and`` for ``or`` / ``is not None`` in the defaults check (some sizes given)."""
    sad = matching_defaults()["sad"]
    frames = _frames()
    np.testing.assert_array_equal(sad_thumbnails(frames, **{k: sad[k] for k in given}),
                                  sad_thumbnails(frames, **thumbnail_options(sad)))


def test_sad_thumbnails_accept_the_smallest_valid_sizes():
    """Kills ``< 2`` / ``<= 1`` for ``< 1`` (sizes) and ``== 2`` for ``== 1`` (patch)."""
    frames = _frames(h=1, w=1)
    assert sad_thumbnails(frames, width=1, height=1, patch=0).shape == (3, 1)
    assert sad_thumbnails(_frames(), width=4, height=2, patch=2).shape == (3, 8)


@pytest.mark.parametrize("sizes, message", [
    (dict(width=8, height=4, patch=1), "patch: must be 0"),
    (dict(width=8, height=6, patch=4), "must divide"),
    (dict(width=6, height=8, patch=4), "must divide"),
    (dict(width=0, height=4, patch=0), "width: must be >= 1, got 0"),
])
def test_sad_thumbnails_refuse_invalid_sizes(sizes, message):
    with pytest.raises(ValueError, match=message):
        sad_thumbnails(_frames(), **sizes)


@pytest.mark.parametrize("shape", [(2, 0, 5, 3), (2, 5, 0, 3)])
def test_sad_thumbnails_refuse_frames_of_empty_spatial_size(shape):
    with pytest.raises(ValueError, match="empty spatial size"):
        sad_thumbnails(np.zeros(shape, np.uint8), width=4, height=2, patch=2)


def test_sad_thumbnails_of_no_frame_are_an_empty_float32_table():
    out = sad_thumbnails(np.zeros((0, 8, 8, 3), np.uint8), width=4, height=2, patch=2)
    assert out.shape == (0, 8) and out.dtype == np.float32


# --- integer difference matrices and window boundaries ----------------------------------------


def test_integer_difference_matrices_match_like_their_float_copy():
    """Kills the dropped integer -> float conversion of single-frame and sequence matching."""
    D = np.random.default_rng(4).integers(0, 50, (30, 20))
    m_int, r_int = single_frame_matches(D, r_window=4)
    m_float, r_float = single_frame_matches(D.astype(np.float64), r_window=4)
    np.testing.assert_array_equal(m_int, m_float)
    np.testing.assert_allclose(r_int, r_float)
    s_int = sequence_search(D, ds=4, r_window=4)
    s_float = sequence_search(D.astype(np.float64), ds=4, r_window=4)
    np.testing.assert_array_equal(s_int.match, s_float.match)
    np.testing.assert_allclose(s_int.score, s_float.score)


def test_single_frame_matching_accepts_a_zero_window():
    """Kills ``<= 0`` / ``< 1`` for ``< 0``: no exclusion window is valid."""
    D = np.array([[0.0, 2.0], [1.0, 0.5]])
    match, _ = single_frame_matches(D, r_window=0)
    np.testing.assert_array_equal(match, [0, 1])


@pytest.mark.parametrize("shape", [(3, 0), (0, 3)])
def test_an_empty_difference_matrix_is_refused(shape):
    """Kills ``and`` for ``or`` and the repeated axis in the emptiness check."""
    with pytest.raises(ValueError, match="must not be empty"):
        single_frame_matches(np.zeros(shape), r_window=2)


# --- fixed examples at input-check boundaries (hypothesis draws them only sometimes) ----------


@pytest.mark.parametrize("metric", ["sad", "sqeuclidean"])
def test_one_feature_per_frame_is_a_valid_difference(metric):
    """Kills ``shape[1] <= 1`` / ``< 2`` in the feature check."""
    reference, query = np.array([[0.0], [2.0], [5.0]]), np.array([[1.0], [5.0]])
    diff = reference - query.T
    expected = np.abs(diff) if metric == "sad" else diff ** 2
    np.testing.assert_allclose(difference_matrix(reference, query, metric=metric), expected)


def test_an_exclusion_zone_of_zero_metres_allows_every_row_travelled_before():
    """Kills ``metres <= 0`` for ``< 0`` in the check (0 m is valid)."""
    allowed = exclusion_limits(4, frames=0, metres=0.0, travelled=np.array([0.0, 1.0, 1.0, 3.0]))
    np.testing.assert_array_equal(allowed, [0, 1, 1, 3])


@pytest.mark.parametrize("kwargs, message", [
    (dict(n_frames=-1), "n_frames must be an integer >= 0"),
    (dict(n_frames=True), "n_frames must be an integer >= 0"),
    (dict(n_frames=4, frames=True), "frames .exclusion zone. must be an integer >= 0"),
    (dict(n_frames=4, frames=-1), "frames .exclusion zone. must be an integer >= 0"),
    (dict(n_frames=4, metres=1.0, travelled=np.zeros(3)), "travelled must be a finite"),
    (dict(n_frames=3, metres=1.0, travelled=np.array([0.0, np.nan, 2.0])),
     "travelled must be a finite"),
])
def test_exclusion_limits_refuse_bad_arguments_naming_them(kwargs, message):
    """Kills ``and`` for ``or`` in each argument check."""
    rest = {key: value for key, value in kwargs.items() if key != "n_frames"}
    with pytest.raises(ValueError, match=message):
        exclusion_limits(kwargs["n_frames"], **rest)


@pytest.mark.parametrize("kwargs, message", [
    (dict(v_min=0.0, v_max=1.0, v_step=0.1), "v_min: must be > 0"),
    (dict(v_min=0.8, v_max=1.1, v_step=0.0), "v_step: must be > 0"),
])
def test_trajectory_velocities_refuse_a_zero_speed_or_step(kwargs, message):
    """Kills ``0 <= v_min`` and ``v_step < 0``."""
    with pytest.raises(ValueError, match=message):
        trajectory_velocities(**kwargs)


# --- the 2026-12-01 matching/ run (mutmut, tests/matching + tests/evaluation) ----------------


def test_thumbnail_options_keep_the_sizes_and_drop_quantise():
    """Kills ``not in`` for ``in`` (an empty dict would silently fall back to 64 x 32)."""
    sad = {"width": 16, "height": 8, "patch": 4, "quantise": True}
    assert thumbnail_options(sad) == {"width": 16, "height": 8, "patch": 4}


@pytest.mark.parametrize("option", [{"chunk_size": 2.5}, {"top_k": 1.5}, {"chunk_size": "3"}])
def test_match_sequences_refuses_non_integer_chunk_size_and_top_k(option):
    """Kills ``and`` for ``or`` in both checks (a bool was the only non-integer tried)."""
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match=next(iter(option))):
        match_sequences(rng.random((8, 4)), rng.random((8, 4)), metric="sad", **option)


def test_a_two_frame_enhancement_window_searches_float64_z_scores():
    """Kills ``// 2 > 1`` for ``> 0`` (the smallest window stored its z-scores as float32)."""
    rng = np.random.default_rng(3)
    reference, query = rng.random((30, 6)), rng.random((12, 6))
    params = SeqSLAMParams.defaults(ds=3, r_window=2)
    result = match_sequences(reference, query, metric="sad", params=params)
    D = difference_matrix(reference, query, metric="sad").astype(np.float64)
    match, score, _ = loop_search(loop_enhance(D, r_window=2), ds=3,
                                  velocities=list(params.velocities()), r_window=2)
    np.testing.assert_array_equal(result.match, match)
    np.testing.assert_allclose(result.score, score, rtol=1e-12, atol=1e-12)


# --- the 2026-12-01 matching/ run, older survivors read one by one ----------------------------

def test_match_loops_without_n_allowed_excludes_the_last_50_frames():
    """The default exclusion zone: query ``q`` may match rows ``0 .. q - 51`` (kills the default
    path replaced by ``_check_allowed(None)`` or ``exclusion_limits(None)``)."""
    from test_loops import looping_route

    from cmal_lcd.matching.loops import match_loops

    features = looping_route(60, laps=2, seed=3)
    params = SeqSLAMParams.defaults(ds=5, r_window=6)
    result = match_loops(features, metric="sad", params=params)
    np.testing.assert_array_equal(result.n_allowed, np.maximum(np.arange(120) - 50, 0))
    scored = result.match >= 0
    assert scored.any()
    assert (result.match[scored] <= np.arange(120)[scored] - 51).all()


def test_match_loops_refuses_a_negative_number_of_allowed_rows():
    from cmal_lcd.matching.loops import match_loops

    features = np.random.default_rng(0).normal(size=(12, 4)).astype(np.float32)
    n_allowed = np.zeros(12, dtype=np.int64)
    n_allowed[11] = -1
    with pytest.raises(ValueError, match=r"0 <= n_allowed\[q\] <= q"):
        match_loops(features, metric="sad", params=SeqSLAMParams.defaults(ds=2, r_window=4),
                    n_allowed=n_allowed)


@pytest.mark.parametrize("r_window", [-2, True, 4.0])
def test_enhance_contrast_refuses_a_window_that_is_not_a_non_negative_integer(r_window):
    """Each condition of the window check on its own: a negative int, a bool, a float."""
    D = np.arange(20, dtype=np.float32).reshape(4, 5)
    with pytest.raises(ValueError, match="r_window: (must be >= 0|expected int, got)"):
        enhance_contrast(D, r_window=r_window)


@pytest.mark.parametrize("patch, message", [(-2, "patch: must be >= 0, got -2"),
                                            (2.0, "patch: expected int, got float")])
def test_sad_thumbnails_refuses_a_negative_or_non_integer_patch(patch, message):
    images = np.zeros((1, 8, 8, 3), dtype=np.uint8)
    with pytest.raises(ValueError, match=message):
        sad_thumbnails(images, width=4, height=4, patch=patch)


def test_seqslam_params_as_dict_round_trips():
    """``as_dict`` is what the stages write into their info files; it must give back the
    same parameters."""
    params = SeqSLAMParams.defaults(ds=7, r_window=6)
    d = params.as_dict()
    assert d["ds"] == 7 and d["r_window"] == 6
    assert SeqSLAMParams.defaults(**d) == params


@pytest.mark.parametrize("shape, patch", [((1, 4, 4), 1), ((1, 8, 6), 4), ((1, 6, 8), 4)])
def test_patch_normalise_refuses_patch_1_and_a_patch_dividing_one_side_only(shape, patch):
    from cmal_lcd.matching.sad import patch_normalise

    with pytest.raises(ValueError, match=f"patch={patch} must be >= 2 and divide"):
        patch_normalise(np.zeros(shape), patch=patch)


def test_a_patch_whose_std_equals_the_flat_threshold_is_normalised_not_zeroed():
    """Flat means a sample std *below* ``FLAT_PATCH_STD`` (1e-3). The patch ``0, 0, 0, 0.002``
    has mean 0.0005 and sample std exactly 1e-3, so it becomes ``-0.5, -0.5, -0.5, 1.5``."""
    from cmal_lcd.matching.sad import FLAT_PATCH_STD, patch_normalise

    assert FLAT_PATCH_STD == 1e-3
    grey = np.array([[[0.0, 0.0], [0.0, 0.002]]])
    np.testing.assert_allclose(patch_normalise(grey, patch=2),
                               [[[-0.5, -0.5], [-0.5, 1.5]]], rtol=1e-12)


@pytest.mark.parametrize("l2", [True, np.True_])
def test_a_code_normalisation_keeps_l2_on_as_a_plain_bool(l2):
    """``l2=True`` (or NumPy's ``True``, as read from an array) stays on, as a Python bool that
    the protocol files can write as JSON, and normalises every code to unit length."""
    import json

    norm = CodeNormalisation(l2=l2)
    assert norm.l2 is True
    assert norm.label == "L2"
    assert json.dumps(norm.l2) == "true"
    reference = np.array([[3.0, 4.0], [0.0, 2.0]])
    query = np.array([[6.0, 8.0]])
    ref_out, query_out = normalise_pair(reference, query, norm)
    np.testing.assert_allclose(ref_out, [[0.6, 0.8], [0.0, 1.0]], rtol=1e-6)
    np.testing.assert_allclose(query_out, [[0.6, 0.8]], rtol=1e-6)


def test_exclusion_limits_refuses_an_infinite_zone_in_metres():
    with pytest.raises(ValueError, match="metres .* must be a finite number >= 0"):
        exclusion_limits(5, frames=0, metres=float("inf"), travelled=np.arange(5.0))


def test_single_frame_matches_refuses_an_infinite_difference():
    D = np.ones((4, 3), dtype=np.float32)
    D[2, 1] = np.inf
    with pytest.raises(ValueError, match="D contains infinite values"):
        single_frame_matches(D, r_window=2)


def test_match_loops_returns_float32_matrices_only_when_asked():
    from test_loops import looping_route

    from cmal_lcd.matching.loops import match_loops

    features = looping_route(20, laps=1, seed=2)
    params = SeqSLAMParams.defaults(ds=2, r_window=4)
    n_allowed = exclusion_limits(20, frames=8)
    lean = match_loops(features, metric="sad", params=params, n_allowed=n_allowed)
    assert lean.D is None and lean.D_hat is None
    full = match_loops(features, metric="sad", params=params, n_allowed=n_allowed,
                       keep_matrices=True)
    assert full.D.dtype == np.float32 and full.D_hat.dtype == np.float32
    assert full.D.shape == full.D_hat.shape == (20, 20)


def test_sequence_top_k_pads_with_minus_1_after_the_distinct_candidates():
    """With 6 reference frames and K = 8 a query has fewer sequence candidates than K: its list
    is distinct reference rows followed by ``-1`` only (kills a fill of +1 or -2)."""
    rng = np.random.default_rng(0)
    reference = rng.normal(size=(6, 4)).astype(np.float32)
    query = rng.normal(size=(12, 4)).astype(np.float32)
    result = match_sequences(reference, query, metric="sad",
                             params=SeqSLAMParams.defaults(ds=3, r_window=2), top_k=8)
    ranked = result.sequence_top_k[result.match >= 0]
    assert len(ranked) and (ranked == -1).any()
    for row in ranked:
        valid = row[row != -1]
        assert (row[len(valid):] == -1).all()
        assert len(set(valid.tolist())) == len(valid) and ((0 <= valid) & (valid < 6)).all()
    # the single-frame list ranks all 6 reference frames, then pads
    for row in result.single_frame_top_k:
        assert sorted(row[:6].tolist()) == list(range(6))
        assert row[6:].tolist() == [-1, -1]


@pytest.mark.parametrize("dtype", [bool, complex])
def test_difference_matrices_must_be_real_valued(dtype):
    with pytest.raises(ValueError, match="D must be real-valued"):
        enhance_contrast(np.ones((3, 3), dtype=dtype), r_window=2)


@pytest.mark.parametrize("kwargs, message", [
    ({"v_max": float("inf")}, "v_max: must be a finite number"),
    ({"v_step": float("inf")}, "v_step: must be a finite number"),
    ({"r_window": True}, "r_window: expected int, got bool"),
    ({"r_window": 4.0}, "r_window: expected int, got float"),
])
def test_seqslam_params_refuse_infinite_speeds_and_non_integer_windows(kwargs, message):
    with pytest.raises(ValueError, match=message):
        SeqSLAMParams.defaults(**kwargs)


def test_match_sequences_reports_progress_as_queries_matched_per_chunk():
    rng = np.random.default_rng(1)
    reference = rng.normal(size=(8, 4)).astype(np.float32)
    query = rng.normal(size=(10, 4)).astype(np.float32)
    calls = []
    match_sequences(reference, query, metric="sad", params=SeqSLAMParams.defaults(ds=3, r_window=2),
                    chunk_size=4, progress=calls.append)
    assert calls == [4, 4, 2]


def test_index_outputs_are_int64_and_kept_matrices_float32():
    """The documented dtypes of outputs built inside the library (not copied from an input):
    single-frame matches, the exclusion zone in metres, the kept ``D`` of ``match_sequences``
    and ``enhance_contrast`` without enhancement (kills ``np.empty`` / ``astype`` without their
    dtype, float64)."""
    D = np.array([[3.0, 1.0], [1.0, 3.0], [2.0, 2.0]], dtype=np.float32)
    match, _ = single_frame_matches(D, r_window=0)
    assert match.dtype == np.int64
    np.testing.assert_array_equal(match, [1, 0])
    limits = exclusion_limits(6, frames=0, metres=1.5, travelled=np.arange(6.0))
    assert limits.dtype == np.int64
    np.testing.assert_array_equal(limits, [0, 0, 1, 2, 3, 4])  # rows r with q - r > 1.5 m
    rng = np.random.default_rng(2)
    result = match_sequences(rng.normal(size=(6, 3)).astype(np.float32),
                             rng.normal(size=(7, 3)).astype(np.float32), metric="sad",
                             params=SeqSLAMParams.defaults(ds=2, r_window=2), keep_matrices=True)
    assert result.D.dtype == np.float32
    unchanged = enhance_contrast(D.astype(np.float64), r_window=0)  # "D unchanged (as float32)"
    assert unchanged.dtype == np.float32
    np.testing.assert_array_equal(unchanged, D)


def test_velocities_stop_at_v_max_when_the_range_is_not_a_multiple_of_the_step():
    """0.8 to 1.6 by 0.3: 0.8, 1.1, 1.4 (1.7 is above ``v_max``); kills rounding the
    number of steps to the nearest integer (2.67 -> 3) instead of keeping whole steps."""
    np.testing.assert_array_equal(trajectory_velocities(v_min=0.8, v_max=1.6, v_step=0.3),
                                  [0.8, 1.1, 1.4])


def test_seqslam_params_store_numpy_scalars_as_plain_python_values():
    """Parameters read from arrays (``np.int64``, ``np.True_``) are stored as ``int`` / ``bool``,
    so ``as_dict`` can be written as JSON."""
    import json

    params = SeqSLAMParams.defaults(ds=np.int64(7), r_window=np.int64(6), enhance=np.True_)
    assert type(params.ds) is int and type(params.r_window) is int
    assert params.enhance is True
    assert json.loads(json.dumps(params.as_dict()))["ds"] == 7


def test_difference_rows_are_float32_for_float64_features():
    rng = np.random.default_rng(4)
    op = difference_module.DifferenceRows(rng.normal(size=(5, 3)), metric="sqeuclidean")
    rows = op(rng.normal(size=(4, 3)))
    assert rows.dtype == np.float32 and rows.shape == (4, 5)


def test_squared_euclidean_differences_are_never_negative():
    """``|q|^2 + |r|^2 - 2 q.r`` rounds below 0 for equal rows of large norm (about -1e-9 on
    the third row here, with this machine's BLAS); a squared distance is clamped at 0 (kills
    the clamp's result thrown away, ``np.maximum`` without ``out=``)."""
    rng = np.random.default_rng(0)
    x = rng.normal(size=(4, 16)) * 10 + 300
    D = difference_matrix(x, x, metric="sqeuclidean")
    assert (D >= 0).all()


@pytest.mark.parametrize("features", [np.ones((2, 3), dtype=bool),
                                      np.ones((2, 3), dtype=complex)])
def test_features_must_be_real_valued(features):
    with pytest.raises(ValueError, match="reference must be a real-valued array"):
        difference_matrix(features, np.ones((2, 3)), metric="sad")


def test_float32_features_with_an_infinite_value_are_refused():
    features = np.ones((2, 3), dtype=np.float32)
    features[0, 0] = np.inf
    with pytest.raises(ValueError, match="reference contains NaN or infinite values"):
        difference_matrix(features, np.ones((2, 3), dtype=np.float32), metric="sad")


@pytest.mark.parametrize("enhance", [True, False])
def test_top_k_values_are_the_scores_and_differences_of_their_rows(enhance):
    """Entry 0 of the sequence values is ``score``; the single-frame values are ``D`` at the
    listed rows; both ascend along K and are NaN exactly where the row is -1 (also across
    chunks, where the enhancement's shift is applied at the end)."""
    rng = np.random.default_rng(3)
    reference = rng.normal(size=(40, 6)).astype(np.float32)
    query = (reference[5:35] + 0.3 * rng.normal(size=(30, 6))).astype(np.float32)
    result = match_sequences(reference, query, metric="sqeuclidean", top_k=5, chunk_size=7,
                             keep_matrices=True, params=SeqSLAMParams.defaults(ds=4, enhance=enhance))
    scored = result.match >= 0
    values, rows = result.sequence_top_k_score, result.sequence_top_k
    np.testing.assert_allclose(values[scored, 0], result.score[scored], rtol=1e-12)
    assert np.array_equal(np.isnan(values), rows == -1)
    assert (np.diff(values[scored], axis=1) >= 0).all()
    sf_rows, sf_values = result.single_frame_top_k, result.single_frame_top_k_difference
    np.testing.assert_array_equal(sf_values, result.D[sf_rows, np.arange(30)[:, None]])
    assert (np.diff(sf_values, axis=1) >= 0).all()
