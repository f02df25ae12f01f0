"""``metric="sad_u8"``: z-scores quantised to bytes, compared by exact integer sums."""

import platform

import numpy as np
import pytest
from llvmlite import binding as llvm_binding

from cmal_lcd.matching import _sad_bytes, difference, difference_matrix, sad_metric
from cmal_lcd.matching.difference import DifferenceRows


def exact_sad_u8(reference, query):
    """The definition, written out: bytes 128 + round(16 z) clipped, mean |a - b| / 16."""
    def to_bytes(x):
        return np.clip(np.rint(np.asarray(x, dtype=np.float64) * 16) + 128, 0, 255)
    a, b = to_bytes(reference), to_bytes(query)
    sums = np.abs(a[:, None, :] - b[None, :, :]).sum(-1)
    return (sums / (16 * reference.shape[1])).astype(np.float32)


def z_scores(n, f, *, seed):
    return (np.random.default_rng(seed).standard_normal((n, f)) * 2.5).astype(np.float32)


# ------------------------------------------------------------------------- quantisation


def test_quantise_maps_z_to_128_plus_16z_rounded_and_clipped():
    z = np.array([[0.0, 1 / 16, -1 / 16, 1.0, -7.875, 7.875, 10.0, -10.0, 0.03, 0.5 / 16]])
    assert _sad_bytes.quantise_z_scores(z)[0, :10].tolist() == [
        128, 129, 127, 144, 2, 254, 255, 0, 128, 128]  # 0.5 step rounds to even


def test_quantise_pads_rows_to_32_bytes_with_zeros():
    q = _sad_bytes.quantise_z_scores(np.full((3, 33), 1.0, dtype=np.float32))
    assert q.shape == (3, 64) and q.dtype == np.uint8
    assert (q[:, :33] == 144).all() and (q[:, 33:] == 0).all()


def test_quantise_takes_integer_features_as_z_scores_too():
    z = np.array([[0, 1, -2, 9]], dtype=np.int16)
    assert _sad_bytes.quantise_z_scores(z)[0, :4].tolist() == [128, 144, 96, 255]


def test_an_8x8_patch_z_score_is_never_clipped():
    # the most extreme patch: one bright pixel among 63 dark ones
    patch = np.zeros(64)
    patch[0] = 1.0
    z = (patch - patch.mean()) / patch.std(ddof=1)
    assert np.abs(z).max() == pytest.approx(7.875)
    q = _sad_bytes.quantise_z_scores(z[None, :])[0, :64].astype(int)
    np.testing.assert_array_equal((q - 128) / 16, np.rint(z * 16) / 16)


# --------------------------------------------------------------------------- difference


@pytest.mark.parametrize("n_ref, n_query, n_feat", [
    (1, 1, 5), (2, 3, 32), (3, 2, 33), (7, 5, 64), (9, 13, 100), (40, 37, 2048)])
def test_sad_u8_equals_the_definition_exactly(n_ref, n_query, n_feat):
    reference = z_scores(n_ref, n_feat, seed=1)
    query = z_scores(n_query, n_feat, seed=2)
    np.testing.assert_array_equal(difference_matrix(reference, query, metric="sad_u8"),
                                  exact_sad_u8(reference, query))


def test_sad_u8_is_within_one_sixteenth_of_sad():
    # each value moves by at most 1/32 when rounded, so each |a - b| by at most 1/16
    reference, query = z_scores(30, 500, seed=3), z_scores(20, 500, seed=4)
    reference, query = np.clip(reference, -7.9, 7.9), np.clip(query, -7.9, 7.9)
    gap = np.abs(difference_matrix(reference, query, metric="sad_u8")
                 - difference_matrix(reference, query, metric="sad"))
    assert gap.max() <= 1 / 16 + 1e-6 and gap.max() > 0


@pytest.mark.parametrize("block", [2, 4, 6, 256])
def test_sad_u8_cells_do_not_depend_on_block_or_query_chunk(monkeypatch, block):
    reference, query = z_scores(23, 70, seed=5), z_scores(11, 70, seed=6)
    whole = difference_matrix(reference, query, metric="sad_u8")
    rows = DifferenceRows(reference, metric="sad_u8")
    monkeypatch.setattr(rows, "_block", block)
    chunks = np.concatenate([rows(query[i:i + 3]) for i in range(0, 11, 3)])
    np.testing.assert_array_equal(chunks, whole.T)


def test_the_plain_loop_fallback_gives_the_same_sums(monkeypatch):
    # CPUs without AVX2 (or numba compiling for a named CPU) use _loop_block
    reference, query = _sad_bytes.quantise_z_scores(z_scores(9, 70, seed=7)), \
        _sad_bytes.quantise_z_scores(z_scores(6, 70, seed=8))
    compiled = np.empty((6, 9), dtype=np.float32)
    _sad_bytes.sad_byte_rows(query, reference, compiled, 4, 1.0)
    monkeypatch.setattr(_sad_bytes, "_block_sums", _sad_bytes._loop_block)
    fallback = np.empty((6, 9), dtype=np.float32)
    _sad_bytes.sad_byte_rows.py_func(query, reference, fallback, 4, 1.0)
    expected = np.abs(query[:, None, :].astype(int) - reference[None, :, :].astype(int)).sum(-1)
    np.testing.assert_array_equal(compiled, expected)
    np.testing.assert_array_equal(fallback, expected)


@pytest.mark.skipif(platform.machine().lower() not in ("x86_64", "amd64")
                    or not llvm_binding.get_host_cpu_features().get("avx2", False),
                    reason="the vpsadbw path needs an x86-64 CPU with AVX2")
def test_an_avx2_cpu_uses_the_packed_byte_instruction(monkeypatch):
    if not _sad_bytes.numba_config.CPU_NAME:  # the kernel was chosen at import
        assert _sad_bytes._block_sums is _sad_bytes._vpsadbw_block
    monkeypatch.setattr(_sad_bytes.numba_config, "CPU_NAME", "")
    assert _sad_bytes.has_avx2()


def test_no_avx2_path_when_numba_compiles_for_a_named_cpu(monkeypatch):
    monkeypatch.setattr(_sad_bytes.numba_config, "CPU_NAME", "generic")
    assert not _sad_bytes.has_avx2()


def test_sad_u8_is_a_metric_of_the_difference_module():
    assert "sad_u8" in difference.METRICS


# ------------------------------------------------------------------------------- config


def test_matching_sad_quantise_selects_the_metric():
    assert sad_metric({"width": 64, "quantise": True}) == "sad_u8"
    assert sad_metric({"width": 64, "quantise": False}) == "sad"
    assert sad_metric({"width": 64}) == "sad"


def test_the_sad_extractor_follows_matching_sad_quantise():
    from cmal_lcd.features.sad import build_sad

    sad = {"width": 16, "height": 8, "patch": 8}
    assert build_sad({"sad": sad, "batch_size": 4}).metric == "sad"
    assert build_sad({"sad": {**sad, "quantise": True}, "batch_size": 4}).metric == "sad_u8"
