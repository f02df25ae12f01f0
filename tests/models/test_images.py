"""preprocess / to_uint8: frames to model tensors in [-1, 1] and back."""

import numpy as np
import pytest
import torch

from cmal_lcd.models import preprocess, to_uint8
from cmal_lcd.models.images import resize_images


def test_preprocess_maps_pixels_to_minus_one_one_channels_first():
    images = np.zeros((2, 8, 8, 3), np.uint8)
    images[0, ..., 0] = 255
    x = preprocess(images, image_size=8)
    assert x.shape == (2, 3, 8, 8) and x.dtype == torch.float32
    assert torch.all(x[0, 0] == 1) and torch.all(x[0, 1] == -1) and torch.all(x[1] == -1)


def test_to_uint8_inverts_preprocess_exactly():
    images = np.random.default_rng(0).integers(0, 256, (3, 16, 16, 3), dtype=np.uint8)
    np.testing.assert_array_equal(to_uint8(preprocess(images, image_size=16)), images)


def test_frames_of_another_size_are_resized():
    images = np.full((2, 48, 64, 3), 100, np.uint8)
    x = preprocess(images, image_size=32)
    assert x.shape == (2, 3, 32, 32)
    torch.testing.assert_close(x, torch.full_like(x, 100 / 127.5 - 1))
    same = np.zeros((1, 8, 8, 3), np.uint8)
    assert resize_images(same, image_size=8) is same


@pytest.mark.parametrize("bad", [np.zeros((2, 8, 8), np.uint8), np.zeros((2, 8, 8, 3), np.float32)])
def test_preprocess_rejects_non_rgb_uint8(bad):
    with pytest.raises(ValueError, match="images"):
        preprocess(bad, image_size=8)
