"""The renderer's threads: how many, and that frames do not depend on the count."""

from __future__ import annotations

import os

import numba
import numpy as np
import pytest
from omegaconf import OmegaConf

from cmal_lcd.kernels import usable_cores
from cmal_lcd.data.world.threads import render_thread_count, run_frame_chunks


@pytest.mark.parametrize("setting, expected", [
    (0, "cores"),   # the default: one thread per core this process may run on
    (1, 1),
    (3, 3),
    (10_000, "cap"),  # never more than numba's thread pool holds
])
def test_the_renderer_uses_the_configured_threads_or_every_core(setting, expected):
    cfg = OmegaConf.create({"runtime": {"threads": 1, "render_threads": setting}})
    cores = len(os.sched_getaffinity(0))
    want = {"cores": min(cores, numba.config.NUMBA_NUM_THREADS),
            "cap": numba.config.NUMBA_NUM_THREADS}.get(expected, expected)
    assert render_thread_count(cfg) == min(want, numba.config.NUMBA_NUM_THREADS)


def test_usable_cores_follows_the_process_affinity():
    assert usable_cores() == len(os.sched_getaffinity(0))


@numba.njit(nogil=True)
def _square_frames(start, stop, frames, out):
    for i in range(start, stop):
        out[i] = frames[i] * frames[i]


@pytest.mark.parametrize("threads", [1, 2])
def test_every_frame_is_computed_once_whatever_the_thread_count(threads):
    frames = np.arange(7, dtype=np.float64)
    out = np.full(7, -1.0)
    before = numba.get_num_threads()
    numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
    try:
        run_frame_chunks(_square_frames, len(frames), frames, out)
    finally:
        numba.set_num_threads(before)
    np.testing.assert_array_equal(out, frames ** 2)
