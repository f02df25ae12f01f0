"""The validation monitor: scores places, not weather, and never changes what is trained."""

import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch

from monitor_helpers import FlattenEncoder, monitor_for, validation_drives

from cmal_lcd.evaluation.monitor import MONITOR_METRICS
from cmal_lcd.models import train_model

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "models"))
from model_helpers import CONDITIONS, tiny_config, weather_frames  # noqa: E402

KEYS = {f"val/{m}" for m in MONITOR_METRICS}


def test_codes_that_identify_places_score_high_and_codes_that_do_not_score_low():
    images, frames, pairs = validation_drives()
    monitor = monitor_for(images, frames, pairs)
    good = monitor(FlattenEncoder())
    assert set(good) == KEYS
    assert good["val/recall_at_100p"] > 0.9 and good["val/single_frame_recall_at_1"] > 0.9
    shuffled = images.copy()
    shuffled[40:] = shuffled[40:][np.random.default_rng(1).permutation(40)]
    bad = monitor_for(shuffled, frames, pairs)(FlattenEncoder())
    assert bad["val/single_frame_recall_at_1"] < 0.2 and bad["val/recall_at_100p"] < 0.2


def test_the_model_mode_is_restored_and_gradients_are_not_recorded():
    images, frames, pairs = validation_drives()
    model = FlattenEncoder()
    model.train()
    monitor_for(images, frames, pairs)(model)
    assert model.training
    model.eval()
    monitor_for(images, frames, pairs)(model)
    assert not model.training


def test_no_validation_pairs_means_nothing_is_logged():
    images, frames, _ = validation_drives()
    assert monitor_for(images, frames, [])(FlattenEncoder()) == {}


def test_a_monitored_run_trains_the_same_weights_and_logs_validation_rows(tmp_path):
    images, labels = weather_frames()
    val_images, val_frames, pairs = validation_drives(12)
    monitor = monitor_for(val_images, val_frames, pairs)
    calls = []

    def recording(model):
        calls.append(model.training)
        return monitor(model)

    paths = {}
    for kind, mon in (("plain", None), ("monitored", recording)):
        paths[kind] = train_model("cmal", tiny_config("cmal", validate_every=2, select="last"),
                                  images, labels,
                                  conditions=CONDITIONS, out_dir=tmp_path / kind, seed=0,
                                  threads=1, device="cpu", monitor=mon)
    plain = torch.load(paths["plain"], weights_only=True)["state_dict"]
    monitored = torch.load(paths["monitored"], weights_only=True)["state_dict"]
    assert plain.keys() == monitored.keys()
    for key in plain:
        assert torch.equal(plain[key], monitored[key]), key
    assert calls == [True, True, True]  # iterations 0, 2 and 4, from inside training
    log = pd.read_csv(tmp_path / "monitored" / "train_log.csv")
    validated = log.dropna(subset=["val/recall_at_100p"])
    assert validated["iteration"].tolist() == [0, 2, 4]
    assert not any(c.startswith("val/") for c in pd.read_csv(tmp_path / "plain" /
                                                             "train_log.csv").columns)


def test_validate_every_must_be_a_multiple_of_log_every(tmp_path):
    images, labels = weather_frames()
    with pytest.raises(ValueError, match="validate_every"):
        train_model("cmal", tiny_config("cmal", validate_every=3), images, labels,
                    conditions=CONDITIONS, out_dir=tmp_path, seed=0, threads=1, device="cpu")


def test_scoring_leaves_torchs_thread_count_as_it_was():
    """numba's parallel kernels set the shared OpenMP thread count; a training run that is
    monitored must keep its own (a changed count changes float rounding and resumes)."""
    images, frames, pairs = validation_drives()
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        monitor_for(images, frames, pairs)(FlattenEncoder())
        assert torch.get_num_threads() == 1
    finally:
        torch.set_num_threads(before)


def test_a_monitored_run_resumed_after_a_kill_trains_the_same_weights(tmp_path):
    images, labels = weather_frames()
    val_images, val_frames, pairs = validation_drives(12)
    monitor = monitor_for(val_images, val_frames, pairs)
    cfg = tiny_config("cmal", iterations=6, validate_every=2)

    class Killed(Exception):
        pass

    def kill_at_3(iteration, logs):
        if iteration == 3:
            raise Killed

    def run(out, **kw):
        return train_model("cmal", cfg, images, labels, conditions=CONDITIONS, out_dir=out,
                           seed=0, threads=1, device="cpu", monitor=monitor, **kw)

    straight = run(tmp_path / "straight")
    with pytest.raises(Killed):
        run(tmp_path / "killed", callback=kill_at_3)
    resumed = run(tmp_path / "killed")
    a = torch.load(straight, weights_only=True)["state_dict"]
    b = torch.load(resumed, weights_only=True)["state_dict"]
    assert all(torch.equal(a[k], b[k]) for k in a)
