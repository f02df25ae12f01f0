"""Per-frame inference time (Table III): raw uint8 frame in, code out.

Two figures per extractor, both medians over ``repeats`` timed calls after ``warmup``
untimed calls:

- ``batch1_ms``: one frame per call (online use on a robot);
- ``batched_ms``: one call on ``batch_size`` frames, divided by ``batch_size``.

Everything the extractor does is timed: resizing, normalisation, the network (or, for SAD,
grey conversion, resizing and patch normalisation). Wall-clock time via
:func:`time.perf_counter`; figures depend on the machine and its load, so the device is named.
"""

from __future__ import annotations

import statistics
import time
from typing import Any, Callable

import numpy as np

from cmal_lcd.features.base import FeatureExtractor, validate_images


def median_call_ms(call: Callable[[int], Any], *, repeats: int, warmup: int) -> float:
    """Median wall time of ``call(i)`` in milliseconds, warm-up calls excluded.

    Parameters
    ----------
    call : callable
        ``call(i)`` for call number ``i`` (warm-up calls get ``i < 0``).
    repeats : int
        Timed calls, >= 1.
    warmup : int
        Untimed calls first, >= 0.
    """
    if repeats < 1:
        raise ValueError(f"repeats: expected >= 1, got {repeats}")
    if warmup < 0:
        raise ValueError(f"warmup: expected >= 0, got {warmup}")
    for i in range(warmup):
        call(-1 - i)
    times = []
    for i in range(repeats):
        start = time.perf_counter()
        call(i)
        times.append(time.perf_counter() - start)
    return 1000.0 * statistics.median(times)


def tile_frames(images: np.ndarray, n: int) -> np.ndarray:
    """The first ``n`` frames of ``images`` repeated cyclically: shape ``(n, H, W, 3)``."""
    if len(images) == 0:
        raise ValueError("images: timing needs at least one frame")
    return np.ascontiguousarray(images[np.arange(n) % len(images)])


def time_per_frame(extractor: FeatureExtractor, images: np.ndarray, *, batch_size: int,
                   repeats: int = 20, warmup: int = 3) -> dict[str, Any]:
    """Per-frame inference time of ``extractor`` at batch 1 and batched.

    Parameters
    ----------
    extractor : FeatureExtractor
    images : ndarray, uint8, shape (N, H, W, 3)
        Frames to time on (N >= 1). Batch-1 calls cycle through them; the batched call uses
        ``batch_size`` of them (repeated cyclically when ``N < batch_size``).
    batch_size : int
        Frames per batched call, >= 1.
    repeats : int
        Timed calls per figure (the median is reported).
    warmup : int
        Untimed calls before each figure.

    Returns
    -------
    dict
        ``batch1_ms``, ``batched_ms`` (per frame), ``batch_size``, ``repeats``, ``warmup``,
        ``device`` (e.g. ``"cpu: <model> (torch 2.13.0, 1 thread)"``).
    """
    images = validate_images(images)
    batch_size = int(batch_size)
    if batch_size < 1:
        raise ValueError(f"batch_size: expected >= 1, got {batch_size}")
    frames = np.ascontiguousarray(images)
    if len(frames) == 0:
        raise ValueError("images: timing needs at least one frame")
    batch = tile_frames(frames, batch_size)

    def one_frame(i: int) -> None:
        k = i % len(frames)
        extractor(frames[k:k + 1])

    def one_batch(i: int) -> None:
        extractor(batch)

    batch1 = median_call_ms(one_frame, repeats=repeats, warmup=warmup)
    batched = median_call_ms(one_batch, repeats=repeats, warmup=warmup) / batch_size
    return {
        "batch1_ms": batch1,
        "batched_ms": batched,
        "batch_size": batch_size,
        "repeats": int(repeats),
        "warmup": int(warmup),
        "device": extractor.describe_device(),
    }
