"""The shared training loop: outputs, determinism, resume after a kill, divergence, settings."""

import csv
import json
import logging
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import yaml
import pytest
import torch
from model_helpers import CONDITIONS, tiny_config, weather_frames

from cmal_lcd.models import TrainingDivergedError, load_trained, train_model
from cmal_lcd.models.base import TrainingBatch
from cmal_lcd.models.config import model_config
from cmal_lcd.models.cmal import CMAL
from cmal_lcd.models.training import (fixed_sample_positions, heldout_split, iteration_draws,
                                      save_torch, step_precision,
                                      write_train_log)


def train(name, out_dir, *, images=None, labels=None, seed=0, **cfg_overrides):
    if images is None:
        images, labels = weather_frames()
    return train_model(name, tiny_config(name, **cfg_overrides), images, labels,
                       conditions=CONDITIONS, out_dir=out_dir, seed=seed, threads=1,
                       device="cpu")


def state_of(path) -> dict:
    return torch.load(Path(path), map_location="cpu", weights_only=True)


def assert_same_weights(a: dict, b: dict) -> None:
    assert a.keys() == b.keys()
    for key in a:
        assert torch.equal(a[key], b[key]), key


def read_log(path) -> list[dict]:
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


class Killed(Exception):
    """Stands for a SIGKILL in the middle of training."""


def kill_after(k):
    def callback(iteration, logs):
        if iteration == k:
            raise Killed(iteration)
    return callback


# ---------------------------------------------------------------- outputs


def test_training_writes_model_log_samples_and_checkpoint(tmp_path, model_name):
    path = train(model_name, tmp_path / model_name)
    assert path == tmp_path / model_name / "model.pt"
    state = state_of(path)
    assert {"name", "config", "conditions", "image_size", "state_dict", "iteration"} <= set(state)
    assert state["name"] == model_name and state["conditions"] == CONDITIONS
    assert state["iteration"] == 4 and state["image_size"] == 16
    rows = read_log(tmp_path / model_name / "train_log.csv")
    assert [int(r["iteration"]) for r in rows] == [2, 4]
    prefixes = {key.split("/")[0] for key in rows[0] if key != "iteration"}
    expected = {"D", "G", "E", "C"} if model_name == "cmal" else {"D", "G", "E"}
    assert prefixes == expected
    if model_name == "cmal":
        assert 0.0 <= float(rows[-1]["C/acc_heldout"]) <= 1.0
    samples = sorted(p.name for p in (tmp_path / model_name / "samples").glob("*.png"))
    assert samples == ["iter_000000.png", "iter_000002.png", "iter_000004.png"]
    assert (tmp_path / model_name / "checkpoints" / "last.pt").is_file()


def test_cmal_sample_grid_has_real_reconstruction_translation_and_generated_rows(tmp_path):
    import cv2

    train("cmal", tmp_path / "cmal")
    grid = cv2.imread(str(tmp_path / "cmal" / "samples" / "iter_000004.png"))
    # rows: real, De(En(x|a)|k) for 3 conditions, De(n|k) for 3 conditions; 4 columns of 16px
    assert grid.shape == (7 * 16 + 6 * 2, 4 * 16 + 3 * 2, 3)


def test_load_trained_gives_the_trained_encoder_in_eval_mode(tmp_path, model_name):
    path = train(model_name, tmp_path / "m")
    model, meta = load_trained(tmp_path / "m")
    assert not model.training
    assert meta["name"] == model_name and meta["iteration"] == 4
    assert "state_dict" not in meta
    assert_same_weights(model.state_dict(), state_of(path)["state_dict"])
    same, _ = load_trained(path)
    x = torch.rand(2, 3, 16, 16) * 2 - 1
    with torch.no_grad():
        assert model.encode(x).shape == (2, 1024)
        torch.testing.assert_close(model.encode(x), same.encode(x))


def test_load_trained_names_a_missing_model(tmp_path):
    with pytest.raises(FileNotFoundError, match="model.pt"):
        load_trained(tmp_path)


def test_training_restores_the_thread_setting(tmp_path):
    before = torch.get_num_threads()
    train("bigan", tmp_path / "m")
    assert torch.get_num_threads() == before


# ---------------------------------------------------------------- determinism and resume


def test_same_seed_gives_the_same_weights_and_another_seed_does_not(tmp_path, model_name):
    path_a, path_b = train(model_name, tmp_path / "a"), train(model_name, tmp_path / "b")
    a, b = state_of(path_a)["state_dict"], state_of(path_b)["state_dict"]
    assert_same_weights(a, b)
    # byte for byte, so that DVC gives a fresh clone's weights the committed hash
    assert Path(path_a).read_bytes() == Path(path_b).read_bytes()
    c = state_of(train(model_name, tmp_path / "c", seed=1))["state_dict"]
    assert any(not torch.equal(a[k], c[k]) for k in a)


def test_a_killed_run_resumes_to_the_same_weights_and_log(tmp_path, model_name):
    reference = train(model_name, tmp_path / "ref", iterations=6)
    images, labels = weather_frames()
    cfg = tiny_config(model_name, iterations=6)
    with pytest.raises(Killed):
        train_model(model_name, cfg, images, labels, conditions=CONDITIONS,
                    out_dir=tmp_path / "run", seed=0, device="cpu", callback=kill_after(3))
    assert not (tmp_path / "run" / "model.pt").exists()
    assert state_of(tmp_path / "run" / "checkpoints" / "last.pt")["iteration"] == 2
    seen = []
    resumed = train_model(model_name, cfg, images, labels, conditions=CONDITIONS,
                          out_dir=tmp_path / "run", seed=0, device="cpu",
                          callback=lambda it, logs: seen.append(it))
    assert seen == [3, 4, 5, 6]  # lost one iteration (3), at most checkpoint_every
    assert_same_weights(state_of(resumed)["state_dict"], state_of(reference)["state_dict"])
    assert (read_log(tmp_path / "run" / "train_log.csv")
            == read_log(tmp_path / "ref" / "train_log.csv"))
    assert ({p.name for p in (tmp_path / "run" / "samples").iterdir()}
            == {p.name for p in (tmp_path / "ref" / "samples").iterdir()})
    assert folder_bytes(tmp_path / "run" / "dvclive") == folder_bytes(tmp_path / "ref" / "dvclive")


def folder_bytes(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file()}


def test_a_sigkilled_process_resumes_to_the_same_weights(tmp_path):
    script = textwrap.dedent(f"""
        import os, signal, sys
        sys.path.insert(0, {str(Path(__file__).parent)!r})
        import torch
        torch.set_num_threads(1)
        from model_helpers import CONDITIONS, tiny_config, weather_frames
        from cmal_lcd.models import train_model
        images, labels = weather_frames()
        def die(iteration, logs):
            if iteration == 5:
                os.kill(os.getpid(), signal.SIGKILL)
        train_model("cmal", tiny_config("cmal", iterations=6), images, labels,
                    conditions=CONDITIONS, out_dir={str(tmp_path / "run")!r}, seed=0,
                    device="cpu", callback=die)
    """)
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, timeout=120)
    assert proc.returncode == -signal.SIGKILL, proc.stderr.decode()[-2000:]
    assert state_of(tmp_path / "run" / "checkpoints" / "last.pt")["iteration"] == 4
    resumed = train("cmal", tmp_path / "run", iterations=6)
    reference = train("cmal", tmp_path / "ref", iterations=6)
    assert_same_weights(state_of(resumed)["state_dict"], state_of(reference)["state_dict"])


def test_more_iterations_continue_a_finished_run(tmp_path):
    train("bigan", tmp_path / "run", iterations=4)
    longer = train("bigan", tmp_path / "run", iterations=6)
    reference = train("bigan", tmp_path / "ref", iterations=6)
    assert_same_weights(state_of(longer)["state_dict"], state_of(reference)["state_dict"])


def test_a_checkpoint_of_another_config_or_dataset_is_not_resumed(tmp_path, caplog):
    train("cmal", tmp_path / "run")
    caplog.set_level(logging.WARNING, logger="cmal_lcd.models.training")
    changed = train("cmal", tmp_path / "run", loss_weights={"recon": 1.0})
    assert "another config" in caplog.text
    fresh = train("cmal", tmp_path / "fresh", loss_weights={"recon": 1.0})
    assert_same_weights(state_of(changed)["state_dict"], state_of(fresh)["state_dict"])
    caplog.clear()
    images, labels = weather_frames(seed=1)
    train("cmal", tmp_path / "run", images=images, labels=labels, loss_weights={"recon": 1.0})
    assert "another config" in caplog.text


# ---------------------------------------------------------------- divergence


def test_a_nan_loss_stops_training_and_keeps_the_last_good_checkpoint(tmp_path, monkeypatch):
    original = CMAL.training_step
    calls = []

    def poisoned(self, batch, optimizers, **kwargs):
        calls.append(1)
        if len(calls) == 3:  # iteration 3: a NaN frame reaches the networks
            batch = TrainingBatch(x=torch.full_like(batch.x, float("nan")),
                                  condition=batch.condition, target=batch.target,
                                  noise=batch.noise)
        return original(self, batch, optimizers, **kwargs)

    monkeypatch.setattr(CMAL, "training_step", poisoned)
    with pytest.raises(TrainingDivergedError, match=r"loss \S+ = nan at iteration 3") as err:
        train("cmal", tmp_path / "run")
    assert "iteration 2" in str(err.value)
    assert not (tmp_path / "run" / "model.pt").exists()
    kept = state_of(tmp_path / "run" / "checkpoints" / "last.pt")
    assert kept["iteration"] == 2
    assert all(torch.isfinite(t).all() for t in kept["model"].values() if t.is_floating_point())


def test_a_huge_learning_rate_diverges_with_a_clear_message(tmp_path, model_name):
    lrs = {"lr_d": 1e30, "lr_g": 1e30}
    with pytest.raises(TrainingDivergedError, match="training diverged: loss .* at iteration"):
        train(model_name, tmp_path / "run", optimizer=lrs)
    assert not (tmp_path / "run" / "model.pt").exists()


# ---------------------------------------------------------------- pieces


def test_heldout_split_is_a_reproducible_partition():
    train_idx, heldout = heldout_split(100, fraction=0.1, seed=3)
    assert len(heldout) == 10
    assert np.array_equal(np.sort(np.concatenate([train_idx, heldout])), np.arange(100))
    again = heldout_split(100, fraction=0.1, seed=3)
    assert np.array_equal(again[1], heldout)
    assert not np.array_equal(heldout_split(100, fraction=0.1, seed=4)[1], heldout)
    assert len(heldout_split(5, fraction=0.0, seed=0)[1]) == 0
    assert len(heldout_split(5, fraction=0.01, seed=0)[1]) == 1


def test_iteration_draws_depend_only_on_seed_and_iteration():
    labels = np.arange(50) % 3
    a = iteration_draws(7, seed=0, labels=labels, batch_size=16, n_conditions=3)
    b = iteration_draws(7, seed=0, labels=labels, batch_size=16, n_conditions=3)
    assert all(np.array_equal(x, y) for x, y in zip(a, b))
    positions, target, _ = a
    assert len(set(positions)) == 16 and np.all(np.diff(positions) > 0)
    assert np.all(target != labels[positions]) and target.max() < 3
    other = iteration_draws(8, seed=0, labels=labels, batch_size=16, n_conditions=3)
    assert not np.array_equal(other[0], positions)
    single = iteration_draws(1, seed=0, labels=np.zeros(4, int), batch_size=16, n_conditions=1)
    assert len(single[0]) == 4 and np.all(single[1] == 0)


def test_fixed_sample_frames_cover_every_condition_in_order():
    labels = np.array([2, 2, 2, 2, 0, 0, 1, 1, 1])
    positions = fixed_sample_positions(labels, count=6, seed=0)
    assert len(positions) == 6 and len(set(positions)) == 6
    assert list(labels[positions]) == [0, 0, 1, 1, 2, 2]


@pytest.mark.parametrize("key, value", [("iterations", 0), ("batch_size", 2.5),
                                        ("log_every", -1), ("heldout_fraction", 1.0)])
def test_training_settings_name_the_bad_key(key, value):
    cfg = tiny_config("cmal", **{key: value})
    with pytest.raises(ValueError, match=rf"^models\.cmal\.{key}: "):
        model_config("cmal", cfg)
    del cfg[key]
    with pytest.raises(ValueError, match=rf"^models\.cmal\.{key}: missing"):
        model_config("cmal", cfg)


def test_bad_labels_are_named(tmp_path):
    images, labels = weather_frames()
    with pytest.raises(ValueError, match="labels"):
        train_model("cmal", tiny_config("cmal"), images, labels + 1, conditions=CONDITIONS,
                    out_dir=tmp_path, seed=0)
    with pytest.raises(ValueError, match="images"):
        train_model("cmal", tiny_config("cmal"), images[..., 0], labels, conditions=CONDITIONS,
                    out_dir=tmp_path, seed=0)


def test_train_log_has_iteration_then_sorted_keys(tmp_path):
    path = write_train_log(tmp_path / "log.csv", [{"iteration": 2, "G/adv": 0.5, "D/loss": 1.0},
                                                  {"iteration": 4, "D/loss": 0.25}])
    assert path.read_text().splitlines() == ["iteration,D/loss,G/adv", "2,1.0,0.5", "4,0.25,"]


# --- which weights model.pt keeps (select) -------------------------------------------------

def scripted_monitor(scores: dict[int, float]):
    """A monitor returning ``scores[iteration]`` at the validated iterations 0, 2, 4, ..."""
    calls = []

    def monitor(model):
        iteration = 2 * len(calls)
        calls.append(iteration)
        return {"val/recall_at_100p": scores[iteration]}

    return monitor


def train_monitored(name, out_dir, scores, *, callback=None, **overrides):
    images, labels = weather_frames()
    cfg = tiny_config(name, iterations=6, validate_every=2, **overrides)
    return train_model(name, cfg, images, labels, conditions=CONDITIONS, out_dir=out_dir,
                       seed=0, device="cpu", monitor=scripted_monitor(scores),
                       callback=callback)


def test_best_validation_keeps_the_best_validated_iteration_never_the_untrained_one(tmp_path):
    path = train_monitored("cmal", tmp_path / "run", {0: 0.9, 2: 0.3, 4: 0.7, 6: 0.5},
                           select="best_validation")
    saved = state_of(path)
    assert (saved["iteration"], saved["trained_iterations"]) == (4, 6)
    # the weights of iteration 4 are those of a 4-iteration run (same seed, same draws)
    four = train("cmal", tmp_path / "four", iterations=4, select="last")
    assert_same_weights(saved["state_dict"], state_of(four)["state_dict"])
    record = json.loads((tmp_path / "run" / "selection.json").read_text())
    assert record == saved["selection"]
    assert (record["select"], record["iteration"], record["score"], record["last_score"]) == (
        "best_validation", 4, 0.7, 0.5)


def test_best_validation_takes_the_earliest_of_equal_scores(tmp_path):
    path = train_monitored("bigan", tmp_path / "run", {0: 0.1, 2: 0.6, 4: 0.6, 6: 0.2},
                           select="best_validation")
    assert state_of(path)["iteration"] == 2


def test_last_keeps_the_last_weights_whatever_validation_says(tmp_path):
    path = train_monitored("cmal", tmp_path / "run", {0: 0.1, 2: 0.9, 4: 0.2, 6: 0.1},
                           select="last")
    saved = state_of(path)
    assert saved["iteration"] == 6 and saved["selection"]["score"] == 0.1
    assert_same_weights(saved["state_dict"],
                        state_of(train("cmal", tmp_path / "ref", iterations=6))["state_dict"])


def test_best_validation_without_validation_keeps_the_last_and_says_why(tmp_path):
    path = train("cmal", tmp_path / "run", iterations=4, select="best_validation")
    record = state_of(path)["selection"]
    assert record["iteration"] == 4 and record["score"] is None
    assert "nothing was validated" in record["note"]


def test_a_resumed_run_remembers_the_best_weights_of_before_the_kill(tmp_path):
    scores = {0: 0.0, 2: 0.8, 4: 0.1, 6: 0.2}
    reference = train_monitored("cmal", tmp_path / "ref", scores, select="best_validation")
    with pytest.raises(Killed):
        train_monitored("cmal", tmp_path / "run", scores, select="best_validation",
                        callback=kill_after(5))
    # the checkpoint of iteration 4 holds the best weights (iteration 2); the resumed process
    # validates only 6, so it can only know iteration 2 was best from the checkpoint
    images, labels = weather_frames()
    cfg = tiny_config("cmal", iterations=6, validate_every=2, select="best_validation")
    resumed = train_model("cmal", cfg, images, labels, conditions=CONDITIONS,
                          out_dir=tmp_path / "run", seed=0, device="cpu",
                          monitor=lambda model: {"val/recall_at_100p": scores[6]})
    assert state_of(resumed)["iteration"] == 2
    assert_same_weights(state_of(resumed)["state_dict"], state_of(reference)["state_dict"])


def test_an_unknown_selection_is_refused_naming_the_key():
    with pytest.raises(ValueError, match="select"):
        model_config("cmal", tiny_config("cmal", select="best"))


# --- precision ------------------------------------------------------------------------------

def test_precision_is_float32_or_bfloat16_and_nothing_else_is_taken():
    assert model_config("cmal", tiny_config("cmal")).precision == "float32"
    assert model_config("cmal", tiny_config("cmal", precision="bfloat16")).precision == \
        "bfloat16"
    with pytest.raises(ValueError, match="precision: must be one of .*got 'float16'"):
        model_config("cmal", tiny_config("cmal", precision="float16"))
    cfg = tiny_config("cmal")
    del cfg["precision"]
    with pytest.raises(ValueError, match=r"^models\.cmal\.precision: missing"):
        model_config("cmal", cfg)
    with pytest.raises(ValueError, match="precision: expected one of"):
        step_precision("float16", "cpu")


def test_a_bfloat16_step_runs_its_products_in_bfloat16_and_a_float32_step_does_not():
    layer = torch.nn.Linear(4, 4)
    with step_precision("float32", "cpu"):
        assert layer(torch.ones(1, 4)).dtype == torch.float32
    with step_precision("bfloat16", "cpu"):
        assert layer(torch.ones(1, 4)).dtype == torch.bfloat16
    assert layer(torch.ones(1, 4)).dtype == torch.float32  # only inside the step


def test_bfloat16_training_is_reproducible_and_trains_other_float32_weights(tmp_path,
                                                                            model_name):
    fp32 = state_of(train(model_name, tmp_path / "fp32"))["state_dict"]
    bf16_a = state_of(train(model_name, tmp_path / "a", precision="bfloat16"))["state_dict"]
    bf16_b = state_of(train(model_name, tmp_path / "b", precision="bfloat16"))["state_dict"]
    assert_same_weights(bf16_a, bf16_b)
    assert all(w.dtype == fp32[k].dtype for k, w in bf16_a.items())  # weights stay float32
    assert any(not torch.equal(fp32[k], bf16_a[k]) for k in fp32)


# --- dvclive --------------------------------------------------------------------------------

def test_training_logs_through_dvclive_params_series_and_last_values(tmp_path):
    train_monitored("cmal", tmp_path / "run", {0: 0.1, 2: 0.2, 4: 0.3, 6: 0.4}, select="last")
    live = tmp_path / "run" / "dvclive"
    params = yaml.safe_load((live / "params.yaml").read_text())
    assert (params["model"], params["seed"], params["iterations"], params["width"]) == (
        "cmal", 0, 6, 4)
    series = (live / "plots" / "metrics" / "val" / "recall_at_100p.tsv").read_text().split()
    assert series == ["step", "recall_at_100p", "0", "0.1", "2", "0.2", "4", "0.3", "6", "0.4"]
    logged = read_log(tmp_path / "run" / "train_log.csv")
    d_loss = (live / "plots" / "metrics" / "D" / "loss.tsv").read_text().split()[3::2]
    assert [float(v) for v in d_loss] == pytest.approx(
        [float(r["D/loss"]) for r in logged if r["D/loss"]], rel=1e-6)
    last = json.loads((live / "metrics.json").read_text())
    assert last["step"] == 6 and last["val"]["recall_at_100p"] == 0.4


def test_resuming_a_checkpoint_without_best_weights_keeps_the_last_and_says_so(tmp_path):
    scores = {0: 0.0, 2: 0.8, 4: 0.1, 6: 0.2}
    train_monitored("cmal", tmp_path / "run", scores, select="best_validation")
    checkpoint = tmp_path / "run" / "checkpoints" / "last.pt"
    state = torch.load(checkpoint, weights_only=False)
    del state["best"]  # as written before `select` existed
    torch.save(state, checkpoint)
    path = train_monitored("cmal", tmp_path / "run", scores, select="best_validation")
    record = state_of(path)["selection"]
    assert record["iteration"] == 6 and "kept no best weights" in record["note"]


def test_a_saved_object_has_the_same_bytes_whatever_the_file_name(tmp_path):
    """``torch.save`` to a file name puts that (random, temporary) name inside the archive."""
    state = {"w": torch.arange(6.0).reshape(2, 3), "iteration": 3}
    a = save_torch(tmp_path / "a" / "model.pt", state)
    b = save_torch(tmp_path / "b" / "other.pt", state)
    assert a.read_bytes() == b.read_bytes()
    assert torch.equal(state_of(a)["w"], state["w"])


def test_bfloat16_on_the_cpu_under_the_avx2_pin_warns_that_it_is_emulated(tmp_path, monkeypatch,
                                                                          caplog):
    monkeypatch.setenv("ONEDNN_MAX_CPU_ISA", "AVX2")
    with caplog.at_level(logging.WARNING, logger="cmal_lcd.models.training"):
        train("cmal", tmp_path / "pinned", iterations=1, precision="bfloat16")
    assert "emulates bfloat16" in caplog.text and "CMAL_LCD_NATIVE_KERNELS=1" in caplog.text
    caplog.clear()
    monkeypatch.setenv("ONEDNN_MAX_CPU_ISA", "AVX512_CORE_AMX")
    with caplog.at_level(logging.WARNING, logger="cmal_lcd.models.training"):
        train("cmal", tmp_path / "native", iterations=1, precision="bfloat16")
    assert "emulates bfloat16" not in caplog.text
