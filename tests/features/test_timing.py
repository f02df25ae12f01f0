"""Table III timing: medians over repeats, warm-up excluded, per frame, device named."""

import numpy as np
import pytest

from cmal_lcd.features import timing
from cmal_lcd.features.base import FeatureExtractor


class FakeClock:
    """``perf_counter`` replacement: returns ``now``, which the timed code advances."""

    def __init__(self):
        self.now = 0.0

    def __call__(self):
        return self.now


def recording_extractor(calls, clock=None, seconds_per_frame=None):
    def encode(images):
        calls.append(len(images))
        if clock is not None:
            clock.now += seconds_per_frame(len(calls)) * len(images)
        return np.zeros((len(images), 2), np.float32)

    return FeatureExtractor(name="toy", label="Toy", metric="sqeuclidean", weights="none",
                            encode=encode, backend="numpy")


def test_warmup_calls_are_made_but_not_timed(monkeypatch):
    clock = FakeClock()
    monkeypatch.setattr(timing.time, "perf_counter", clock)
    durations = []

    def call(i):
        clock.now += 5.0 if i < 0 else [0.001, 0.003, 0.002][i]
        durations.append(i)

    ms = timing.median_call_ms(call, repeats=3, warmup=2)
    assert durations == [-1, -2, 0, 1, 2]
    assert ms == pytest.approx(2.0)


def test_batch1_and_batched_figures_are_per_frame_medians(monkeypatch, frames):
    clock = FakeClock()
    monkeypatch.setattr(timing.time, "perf_counter", clock)
    calls = []
    # 10 ms per frame at batch 1, 2 ms per frame in a batch; warm-up calls cost 1 s per frame
    n_warm, n_rep = 2, 3

    def cost(k):
        in_batch1 = k <= n_warm + n_rep
        index = k - 1 if in_batch1 else k - 1 - (n_warm + n_rep)
        if index < n_warm:
            return 1.0
        return 0.010 if in_batch1 else 0.002

    extractor = recording_extractor(calls, clock, cost)
    result = timing.time_per_frame(extractor, frames, batch_size=8, repeats=n_rep, warmup=n_warm)
    assert calls == [1] * (n_warm + n_rep) + [8] * (n_warm + n_rep)  # batch tiled from 6 frames
    assert result["batch1_ms"] == pytest.approx(10.0)
    assert result["batched_ms"] == pytest.approx(2.0)
    assert result["batch_size"] == 8 and result["repeats"] == n_rep and result["warmup"] == n_warm
    assert result["device"].startswith("cpu") and "numpy" in result["device"]


def test_tiled_batch_cycles_through_the_frames(frames):
    batch = timing.tile_frames(frames, 8)
    assert batch.shape == (8,) + frames.shape[1:]
    np.testing.assert_array_equal(batch[6], frames[0])
    np.testing.assert_array_equal(batch[:6], frames)


@pytest.mark.parametrize("kw, name", [({"repeats": 0}, "repeats"), ({"warmup": -1}, "warmup"),
                                      ({"batch_size": 0}, "batch_size")])
def test_bad_timing_parameters_are_rejected(frames, kw, name):
    args = {"batch_size": 2, "repeats": 1, "warmup": 0, **kw}
    with pytest.raises(ValueError, match=name):
        timing.time_per_frame(recording_extractor([]), frames, **args)


def test_real_clock_gives_positive_figures(frames):
    result = timing.time_per_frame(recording_extractor([]), frames, batch_size=2, repeats=2,
                                   warmup=1)
    assert result["batch1_ms"] > 0 and result["batched_ms"] > 0
