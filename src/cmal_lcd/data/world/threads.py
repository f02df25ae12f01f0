"""Frames in parallel: a ``nogil`` numba kernel over contiguous chunks of frames, one thread each.

Every frame is computed by exactly one thread with the same code, so results do not depend on
the number of threads (:func:`numba.get_num_threads`, set by the stages from
``runtime.render_threads``). Plain ``njit(nogil=True)`` kernels compile several times faster than
``parallel=True`` ones.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from typing import Any, Callable

import numba
import numpy as np
from omegaconf import DictConfig, OmegaConf

from cmal_lcd.kernels import usable_cores


def render_thread_count(cfg: Any) -> int:
    """Threads that render frames: ``runtime.render_threads``, 0 (or absent) meaning one per
    usable core (:func:`usable_cores`); at most numba's ``NUMBA_NUM_THREADS``."""
    threads = int(OmegaConf.select(cfg, "runtime.render_threads", default=0) or 0) \
        if isinstance(cfg, DictConfig) else 0
    if threads <= 0:
        threads = usable_cores()
    return max(1, min(threads, numba.config.NUMBA_NUM_THREADS))


def set_render_threads(cfg: Any) -> None:
    """Numba threads of the renderer from :func:`render_thread_count` (frames do not depend on
    it: :func:`run_frame_chunks`)."""
    numba.set_num_threads(render_thread_count(cfg))


def run_frame_chunks(kernel: Callable[..., Any], n_frames: int, *args: Any) -> None:
    """Call ``kernel(start, stop, *args)`` over ``[0, n_frames)`` split into one chunk per thread.

    Parameters
    ----------
    kernel : callable
        A ``nogil`` numba function processing frames ``start .. stop - 1``.
    n_frames : int
    *args
        Passed to every call (output arrays are written in place, disjoint per chunk).
    """
    threads = min(numba.get_num_threads(), n_frames)
    if threads <= 1:
        kernel(0, n_frames, *args)
        return
    bounds = np.linspace(0, n_frames, threads + 1).astype(np.int64)
    with ThreadPoolExecutor(max_workers=threads) as pool:
        futures = [pool.submit(kernel, int(a), int(b), *args)
                   for a, b in zip(bounds[:-1], bounds[1:])]
        for future in futures:
            future.result()
