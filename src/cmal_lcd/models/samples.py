"""Sample grids: rows of frames tiled into one image, encoded as PNG."""

from __future__ import annotations

from typing import Sequence

import cv2
import numpy as np


def image_grid(rows: Sequence[np.ndarray], *, gap: int = 2) -> np.ndarray:
    """Tile rows of frames into one image, separated by ``gap`` white pixels.

    Parameters
    ----------
    rows : sequence of ndarray, uint8, shape (n, H, W, 3)
        Every row has the same ``n``, ``H`` and ``W``.
    gap : int
        Pixels between tiles.

    Returns
    -------
    ndarray, uint8, shape (R*H + (R-1)*gap, n*W + (n-1)*gap, 3)
    """
    if not rows:
        raise ValueError("rows: expected at least one row")
    shape = rows[0].shape
    for i, row in enumerate(rows):
        if row.shape != shape or row.dtype != np.uint8 or row.ndim != 4:
            raise ValueError(f"rows[{i}]: expected uint8 {shape}, got {row.dtype} {row.shape}")
    n, h, w, _ = shape
    grid = np.full((len(rows) * h + (len(rows) - 1) * gap, n * w + (n - 1) * gap, 3), 255,
                   dtype=np.uint8)
    for r, row in enumerate(rows):
        for c, frame in enumerate(row):
            grid[r * (h + gap):r * (h + gap) + h, c * (w + gap):c * (w + gap) + w] = frame
    return grid


def png_bytes(image: np.ndarray) -> bytes:
    """Encode an RGB ``uint8 (H, W, 3)`` image as PNG bytes."""
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(image[..., ::-1]))
    if not ok:
        raise ValueError("image: PNG encoding failed")
    return buf.tobytes()
