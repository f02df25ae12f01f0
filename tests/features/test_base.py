"""The FeatureExtractor contract: validated frames in, one code per frame out."""

import numpy as np
import pytest

from cmal_lcd.features.base import (FeatureExtractor, check_finite_codes, encode_in_batches,
                                    first_nonfinite_row)


def mean_colour(images):
    return images.reshape(len(images), -1, 3).mean(axis=1).astype(np.float32)


def make(encode=mean_colour, **kw):
    return FeatureExtractor(name="toy", label="Toy", metric="sqeuclidean", weights="none",
                            encode=encode, **kw)


def test_call_returns_one_code_per_frame(frames):
    codes = make()(frames)
    assert codes.shape == (len(frames), 3)
    np.testing.assert_allclose(codes[2], frames[2].reshape(-1, 3).mean(axis=0), rtol=1e-6)


@pytest.mark.parametrize("bad", [np.zeros((2, 8, 8, 3), np.float32), np.zeros((2, 8, 8), np.uint8),
                                 np.zeros((8, 8, 3), np.uint8)])
def test_frames_must_be_uint8_rgb_batches(bad):
    with pytest.raises(ValueError, match="images"):
        make()(bad)


def test_an_encoder_returning_the_wrong_rows_is_caught(frames):
    with pytest.raises(ValueError, match="toy"):
        make(encode=lambda im: np.zeros((len(im) + 1, 4), np.float32))(frames)


def test_metric_must_be_known():
    with pytest.raises(ValueError, match="metric"):
        FeatureExtractor(name="x", label="X", metric="cosine", weights="", encode=mean_colour)


def test_batched_encoding_equals_one_call(frames):
    whole = mean_colour(frames)
    for batch_size in (1, 4, 6, 100):
        np.testing.assert_array_equal(
            encode_in_batches(frames, mean_colour, batch_size=batch_size), whole)


def test_batches_have_the_requested_size(frames):
    sizes = []
    encode_in_batches(frames, lambda b: sizes.append(len(b)) or mean_colour(b), batch_size=4)
    assert sizes == [4, 2]


@pytest.mark.parametrize("batch_size", [0, -3])
def test_batch_size_must_be_positive(frames, batch_size):
    with pytest.raises(ValueError, match="batch_size"):
        encode_in_batches(frames, mean_colour, batch_size=batch_size)


def test_nonfinite_codes_are_reported_with_method_and_first_bad_frame():
    codes = np.ones((5, 3), np.float32)
    codes[3, 1] = np.inf
    codes[4, 0] = np.nan
    assert first_nonfinite_row(codes) == 3
    with pytest.raises(ValueError, match=r"cmal: .*first bad frame: test row 3.*2 bad frames"):
        check_finite_codes(codes, method="cmal")


def test_finite_and_integer_codes_pass():
    assert first_nonfinite_row(np.zeros((2, 2), np.float32)) == -1
    assert first_nonfinite_row(np.zeros((2, 2), np.uint8)) == -1
    check_finite_codes(np.zeros((2, 2), np.uint8), method="sad")


def test_device_description_names_library_and_threads():
    import torch

    torch_desc = make(backend="torch").describe_device()
    assert torch_desc.startswith("cpu") and f"torch {torch.__version__}" in torch_desc
    assert "thread" in torch_desc
    assert f"numpy {np.__version__}" in make(backend="numpy").describe_device()
