"""Sample grids: rows of frames tiled with gaps, PNG bytes that decode to the same image."""

import cv2
import numpy as np
import pytest

from cmal_lcd.models.samples import image_grid, png_bytes


def test_grid_places_each_frame_in_its_row_and_column():
    rows = [np.stack([np.full((4, 5, 3), 10 * r + c, np.uint8) for c in range(3)])
            for r in range(2)]
    grid = image_grid(rows, gap=1)
    assert grid.shape == (2 * 4 + 1, 3 * 5 + 2, 3)
    assert np.all(grid[5:9, 12:17] == 12)
    assert np.all(grid[4] == 255)


def test_grid_rejects_rows_of_different_shapes():
    with pytest.raises(ValueError, match=r"rows\[1\]"):
        image_grid([np.zeros((2, 4, 4, 3), np.uint8), np.zeros((3, 4, 4, 3), np.uint8)])


def test_png_bytes_round_trip_rgb():
    image = np.random.default_rng(0).integers(0, 256, (6, 7, 3), dtype=np.uint8)
    decoded = cv2.imdecode(np.frombuffer(png_bytes(image), np.uint8), cv2.IMREAD_COLOR)
    np.testing.assert_array_equal(decoded[..., ::-1], image)
