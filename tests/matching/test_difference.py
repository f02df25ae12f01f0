"""Difference matrix: orientation, SAD and squared Euclidean against a plain loop, chunking."""

import numpy as np
import pytest
from seqslam_loops import loop_difference

from cmal_lcd.matching import difference, difference_matrix


@pytest.fixture
def features():
    rng = np.random.default_rng(0)
    return rng.normal(size=(7, 37)).astype(np.float32), rng.normal(size=(5, 37)).astype(np.float32)


@pytest.mark.parametrize("metric", ["sad", "sqeuclidean", "sqeuclidean_f32"])
def test_rows_are_reference_columns_are_query(features, metric):
    reference, query = features
    D = difference_matrix(reference, query, metric=metric)
    assert D.shape == (7, 5) and D.dtype == np.float32 and D.flags.c_contiguous


@pytest.mark.parametrize("metric", ["sad", "sqeuclidean", "sqeuclidean_f32"])
def test_equals_the_plain_loop(features, metric):
    reference, query = features
    np.testing.assert_allclose(difference_matrix(reference, query, metric=metric),
                               loop_difference(reference, query, metric=metric), rtol=2e-6)


def test_float32_codes_differ_from_float64_by_their_rounding_only():
    """``sqeuclidean_f32`` is the same formula in float32: each cell within about 1e-6 of the
    squared norms (the documented error; measured here 0.94e-6 with OpenBLAS's Haswell kernels
    and 1.14e-6 with its AVX-512 SkylakeX ones, so the bound is 2e-6), computed in float32 (so
    not equal to float64)."""
    rng = np.random.default_rng(5)
    reference = (3.0 + rng.normal(size=(40, 1024))).astype(np.float32)
    query = (reference + 0.5 * rng.normal(size=(40, 1024))).astype(np.float32)
    exact = difference_matrix(reference, query, metric="sqeuclidean")
    fast = difference_matrix(reference, query, metric="sqeuclidean_f32")
    scale = max(np.einsum("ij,ij->i", x, x).max() for x in (reference, query))
    assert np.abs(fast - exact).max() <= 2e-6 * scale
    assert not np.array_equal(fast, exact)
    assert (fast >= 0).all() and fast.dtype == np.float32
    np.testing.assert_array_equal(fast.argmin(axis=0), exact.argmin(axis=0))


def test_sad_is_the_mean_absolute_difference_on_a_hand_example():
    reference = np.array([[0.0, 0.0, 0.0, 0.0], [1.0, 2.0, 3.0, 4.0]])
    query = np.array([[1.0, -1.0, 2.0, 0.0]])
    np.testing.assert_array_equal(difference_matrix(reference, query, metric="sad")[:, 0],
                                  [1.0, (0 + 3 + 1 + 4) / 4])


def test_sad_accepts_uint8_thumbnails_without_wrapping():
    # uint8 subtraction would wrap modulo 256 (a known bug of a SeqSLAM port)
    reference = np.array([[10, 250]], dtype=np.uint8)
    query = np.array([[250, 10]], dtype=np.uint8)
    assert difference_matrix(reference, query, metric="sad")[0, 0] == 240.0


def test_sqeuclidean_keeps_small_distances_of_near_duplicate_codes():
    rng = np.random.default_rng(1)
    codes = (100 + rng.normal(size=(3, 1024))).astype(np.float32)  # large norms
    near = codes + np.float32(1e-3)
    D = difference_matrix(codes, near, metric="sqeuclidean")
    expected = loop_difference(codes, near, metric="sqeuclidean")
    np.testing.assert_allclose(np.diag(D), np.diag(expected), rtol=1e-3)
    assert (D >= 0).all()


def test_sad_every_cell_is_independent_of_block_and_chunk_sizes(monkeypatch):
    rng = np.random.default_rng(2)
    reference = rng.normal(size=(23, 50)).astype(np.float32)
    query = rng.normal(size=(9, 50)).astype(np.float32)
    whole = difference_matrix(reference, query, metric="sad")
    monkeypatch.setattr(difference, "CHUNK_BYTES", 8 * 23 * 2)  # 2 queries per chunk
    op = difference.DifferenceRows(reference, metric="sad")
    op._block = 4
    np.testing.assert_array_equal(difference_matrix(reference, query, metric="sad"), whole)
    np.testing.assert_array_equal(op(query).T, whole)


@pytest.mark.parametrize("reference, query, match", [
    (np.zeros((3, 4)), np.zeros((2, 5)), "features"),
    (np.zeros((3,)), np.zeros((2, 3)), "reference"),
    (np.zeros((3, 4)), np.full((2, 4), np.nan), "query"),
    (np.zeros((0, 4)), np.zeros((2, 4)), "reference"),
])
def test_invalid_inputs_raise_naming_them(reference, query, match):
    with pytest.raises(ValueError, match=match):
        difference_matrix(reference, query, metric="sad")


def test_unknown_metric_raises():
    with pytest.raises(ValueError, match="metric"):
        difference_matrix(np.zeros((2, 2)), np.zeros((2, 2)), metric="cosine")


def test_sad_cell_values_do_not_depend_on_the_query_batch():
    # the kernel computes 4 queries x 4 references at once: a cell must not depend on its slot
    rng = np.random.default_rng(3)
    reference = rng.normal(size=(13, 100)).astype(np.float32)
    query = rng.normal(size=(11, 100)).astype(np.float32)
    op = difference.DifferenceRows(reference, metric="sad")
    batch = op(query)
    for start, stop in [(0, 1), (1, 2), (2, 5), (3, 11), (5, 6)]:
        np.testing.assert_array_equal(op(query[start:stop]), batch[start:stop])


@pytest.mark.parametrize("metric", ["sqeuclidean", "sqeuclidean_f32"])
def test_rows_can_be_written_into_a_given_buffer(metric):
    rng = np.random.default_rng(4)
    op = difference.DifferenceRows(rng.normal(size=(6, 8)), metric=metric)
    buffer = np.empty((3, 6), dtype=np.float32)
    query = rng.normal(size=(3, 8))
    assert op(query, out=buffer) is buffer
    np.testing.assert_allclose(buffer, loop_difference(op._reference, query,
                                                       metric=metric).T, rtol=1e-5)
    with pytest.raises(ValueError, match="out"):
        op(query, out=np.empty((3, 6)))
