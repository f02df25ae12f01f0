"""SAD thumbnails: grey, INTER_AREA downsampling, patch normalisation to float z-scores."""

import cv2
import numpy as np
import pytest

from cmal_lcd.matching import sad_thumbnails


@pytest.fixture
def images():
    return np.random.default_rng(0).integers(0, 256, (3, 48, 80, 3), dtype=np.uint8)


def test_shape_and_dtype(images):
    out = sad_thumbnails(images, width=16, height=8, patch=4)
    assert out.shape == (3, 8 * 16) and out.dtype == np.float32


def test_every_patch_has_zero_mean_and_unit_sample_std(images):
    out = sad_thumbnails(images, width=16, height=8, patch=4).reshape(3, 2, 4, 4, 4)
    np.testing.assert_allclose(out.mean(axis=(2, 4)), 0.0, atol=1e-6)
    np.testing.assert_allclose(out.std(axis=(2, 4), ddof=1), 1.0, rtol=1e-5)


def test_matches_grey_weights_area_resize_and_patch_zscores_written_out(images):
    grey = 0.2989 * images[..., 0] + 0.5870 * images[..., 1] + 0.1140 * images[..., 2]
    small = np.stack([cv2.resize(g, (16, 8), interpolation=cv2.INTER_AREA) for g in grey])
    expected = np.empty_like(small)
    for n in range(3):
        for r in range(0, 8, 4):
            for c in range(0, 16, 4):
                p = small[n, r:r + 4, c:c + 4]
                expected[n, r:r + 4, c:c + 4] = (p - p.mean()) / p.std(ddof=1)
    out = sad_thumbnails(images, width=16, height=8, patch=4)
    np.testing.assert_allclose(out, expected.reshape(3, -1), rtol=1e-5, atol=1e-5)


def test_constant_patches_become_zero_not_nan():
    images = np.zeros((2, 32, 64, 3), dtype=np.uint8)  # black tunnel frames
    images[1, :, 32:] = 200
    out = sad_thumbnails(images)
    assert np.isfinite(out).all()
    assert (out == 0).all()


def test_uniform_image_stays_flat_after_non_integer_resampling():
    # INTER_AREA over a 500x700 uniform image leaves ~1e-6 noise; it must not become z-scores
    images = np.full((1, 500, 700, 3), 77, dtype=np.uint8)
    assert (sad_thumbnails(images) == 0).all()


def test_grey_input_equals_the_same_grey_repeated_as_rgb(images):
    grey = images[..., 1]
    rgb = np.repeat(grey[..., None], 3, axis=3)
    np.testing.assert_allclose(sad_thumbnails(grey, width=16, height=8, patch=4),
                               sad_thumbnails(rgb, width=16, height=8, patch=4), atol=1e-4)


def test_patch_zero_gives_the_resized_grey_levels(images):
    out = sad_thumbnails(images, width=16, height=8, patch=0)
    grey = 0.2989 * images[..., 0] + 0.5870 * images[..., 1] + 0.1140 * images[..., 2]
    expected = cv2.resize(grey[0], (16, 8), interpolation=cv2.INTER_AREA)
    np.testing.assert_allclose(out[0], expected.ravel(), rtol=1e-6)


def test_frames_already_at_thumbnail_size_are_not_resampled():
    images = np.random.default_rng(1).integers(0, 256, (2, 32, 64, 3), dtype=np.uint8)
    out = sad_thumbnails(images, patch=0)
    grey = 0.2989 * images[..., 0] + 0.5870 * images[..., 1] + 0.1140 * images[..., 2]
    np.testing.assert_allclose(out, grey.reshape(2, -1).astype(np.float32))


def test_batches_give_the_same_result_as_single_images():
    """600 frames are three batches, converted on threads: every row lands where it belongs."""
    images = np.random.default_rng(2).integers(0, 256, (600, 16, 32, 3), dtype=np.uint8)
    together = sad_thumbnails(images, width=16, height=8, patch=4)
    alone = np.concatenate([sad_thumbnails(images[i:i + 1], width=16, height=8, patch=4)
                            for i in range(len(images))])
    np.testing.assert_array_equal(together, alone)


@pytest.mark.parametrize("kwargs, name", [
    ({"patch": 5}, "patch"), ({"patch": 1}, "patch"), ({"width": 0}, "width"),
    ({"height": -3}, "height"),
])
def test_invalid_options_raise_naming_them(images, kwargs, name):
    with pytest.raises(ValueError, match=name):
        sad_thumbnails(images, **kwargs)


@pytest.mark.parametrize("bad", [np.zeros((2, 8, 8, 4), np.uint8), np.zeros((8, 8), np.uint8),
                                 np.zeros((2, 8, 8, 3), np.float32)])
def test_invalid_images_raise(bad):
    with pytest.raises(ValueError, match="images"):
        sad_thumbnails(bad)
