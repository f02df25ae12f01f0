"""Conversions between ``uint8 (N, H, W, 3)`` RGB frames and model tensors in ``[-1, 1]``."""

from __future__ import annotations

import cv2
import numpy as np
import torch


def _validate_images(images: np.ndarray) -> np.ndarray:
    images = np.asarray(images)
    if images.dtype != np.uint8 or images.ndim != 4 or images.shape[-1] != 3:
        raise ValueError(f"images: expected uint8 (N, H, W, 3), got {images.dtype} {images.shape}")
    return images


def resize_images(images: np.ndarray, *, image_size: int) -> np.ndarray:
    """Resize frames to ``image_size x image_size`` (area interpolation); no copy if equal.

    Parameters
    ----------
    images : ndarray, uint8, shape (N, H, W, 3)

    Returns
    -------
    ndarray, uint8, shape (N, image_size, image_size, 3)
    """
    images = _validate_images(images)
    if images.shape[1:3] == (image_size, image_size):
        return images
    out = np.empty((images.shape[0], image_size, image_size, 3), dtype=np.uint8)
    for i, frame in enumerate(images):
        out[i] = cv2.resize(np.ascontiguousarray(frame), (image_size, image_size),
                            interpolation=cv2.INTER_AREA)
    return out


def preprocess(images: np.ndarray, *, image_size: int) -> torch.Tensor:
    """Frames to the models' input.

    Parameters
    ----------
    images : ndarray, uint8, shape (N, H, W, 3)
        RGB frames of any size; resized when not ``image_size`` square.
    image_size : int
        Side of the model input.

    Returns
    -------
    Tensor, float32, shape (N, 3, image_size, image_size)
        Values in ``[-1, 1]`` (``pixel / 127.5 - 1``), on the CPU.
    """
    resized = np.ascontiguousarray(resize_images(images, image_size=image_size))
    if not resized.flags.writeable:  # a read-only memory map: torch warns on sharing it
        resized = resized.copy()
    x = torch.from_numpy(resized).permute(0, 3, 1, 2).float()
    return x.div_(127.5).sub_(1.0).contiguous()


def to_uint8(x: torch.Tensor) -> np.ndarray:
    """Model output back to frames.

    Parameters
    ----------
    x : Tensor, shape (N, 3, H, W)
        Values in ``[-1, 1]`` (clipped).

    Returns
    -------
    ndarray, uint8, shape (N, H, W, 3)
    """
    pixels = ((x.detach().float().cpu().clamp(-1, 1) + 1) * 127.5).round()
    return pixels.to(torch.uint8).permute(0, 2, 3, 1).contiguous().numpy()
