"""Progress of long steps: a bar on a terminal, a plain INFO line every interval otherwise."""

import logging

import numpy as np
import pandas as pd
import pytest

from cmal_lcd.evaluation import loop_closure
from cmal_lcd.matching import SeqSLAMParams, match_sequences
from cmal_lcd.progress import Progress


class FakeClock:
    def __init__(self):
        self.now = 100.0

    def __call__(self):
        return self.now


def test_without_a_terminal_a_line_is_logged_once_per_interval(caplog):
    clock = FakeClock()
    log = logging.getLogger("cmal_lcd.test_progress")
    with caplog.at_level(logging.INFO, logger=log.name):
        with Progress(100, desc="render route1", unit="frame", logger=log, terminal=False,
                      interval=30.0, clock=clock) as bar:
            for _ in range(10):
                clock.now += 10.0  # 10 frames every 10 s: 1 frame/s
                bar.update(10)
    lines = [r.getMessage() for r in caplog.records]
    # at 30, 60 and 90 s (every third update), never more often
    assert lines == ["render route1: 30/100 frames (30%), 1 frames/s, about 1 min 10 s left",
                     "render route1: 60/100 frames (60%), 1 frames/s, about 40 s left",
                     "render route1: 90/100 frames (90%), 1 frames/s, about 10 s left"]
    assert all(r.levelno == logging.INFO and r.name == log.name for r in caplog.records)


def test_a_short_loop_logs_nothing(caplog):
    clock = FakeClock()
    with caplog.at_level(logging.INFO):
        with Progress(5, desc="evaluate", unit="pair", terminal=False, clock=clock) as bar:
            for _ in range(5):
                clock.now += 1.0
                bar.update()
    assert caplog.records == []


def test_on_a_terminal_a_tqdm_bar_counts_the_units(capsys):
    with Progress(7, desc="match", unit="query", terminal=True) as bar:
        bar.update(3)
        bar.update(4)
        assert bar._bar is not None and bar._bar.n == 7
    assert bar._bar is None  # closed, removed from the screen


def test_matching_reports_every_query_once_through_the_callback():
    rng = np.random.default_rng(0)
    reference = rng.normal(size=(40, 6)).astype(np.float32)
    query = reference[:35] + 0.1 * rng.normal(size=(35, 6)).astype(np.float32)
    done = []
    plain = match_sequences(reference, query, metric="sad", chunk_size=8)
    result = match_sequences(reference, query, metric="sad", chunk_size=8, progress=done.append)
    assert done == [8, 8, 8, 8, 3]
    np.testing.assert_array_equal(result.match, plain.match)


def test_the_pair_loop_logs_its_progress(caplog, monkeypatch):
    monkeypatch.setattr(loop_closure, "LOG_INTERVAL_S", 0.0)  # a line after every pair
    rng = np.random.default_rng(1)
    world = np.cumsum(rng.normal(size=(60, 6)), axis=0)
    codes = np.concatenate([world, world + 0.1 * rng.normal(size=world.shape)]).astype(
        np.float32)
    frames = pd.DataFrame({"drive": ["a"] * 60 + ["b"] * 60})
    pairs = [["r", "a", "b", "a-b"], ["r", "b", "a", "b-a"]]
    with caplog.at_level(logging.INFO, logger="cmal_lcd.evaluation.loop_closure"):
        results = list(loop_closure.evaluate_drive_pairs(
            codes, frames, pairs, metric="sqeuclidean", params=SeqSLAMParams.defaults(ds=5),
            d_thresh=2, ground_truth="index", pose_tolerance=0.0, progress="evaluate sad"))
    assert [pair for _, pair, _ in results] == ["a-b", "b-a"]
    lines = [r.getMessage() for r in caplog.records if r.name.endswith("loop_closure")]
    assert [line.split(",")[0] for line in lines] == ["evaluate sad: 1/2 pairs (50%)",
                                                      "evaluate sad: 2/2 pairs (100%)"]


@pytest.mark.parametrize("progress", [None, "evaluate"])
def test_progress_does_not_change_the_pair_results(progress):
    rng = np.random.default_rng(2)
    world = np.cumsum(rng.normal(size=(50, 4)), axis=0)
    codes = np.concatenate([world, world + 0.2 * rng.normal(size=world.shape)]).astype(
        np.float32)
    frames = pd.DataFrame({"drive": ["a"] * 50 + ["b"] * 50})
    (_, _, evaluation), = loop_closure.evaluate_drive_pairs(
        codes, frames, [["r", "a", "b", "a-b"]], metric="sqeuclidean",
        params=SeqSLAMParams.defaults(ds=5), d_thresh=2, ground_truth="index", pose_tolerance=0.0,
        progress=progress)
    assert evaluation.metrics["n_scored"] == 45
