"""Stage ``train``: reads the dataset's training split, trains, writes models/<name>/."""

import json
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch
from omegaconf import OmegaConf

from cmal_lcd.matching import matching_defaults  # noqa: E402
from cmal_lcd.models import load_trained  # noqa: E402
from cmal_lcd.stages import train  # noqa: E402

sys.path.insert(0, str(Path(__file__).parents[1] / "models"))
from model_helpers import tiny_config  # noqa: E402

torch.set_num_threads(1)

CONDITIONS = ["sunny", "foggy", "rainy"]
N_PLACES = 8


@pytest.fixture
def dataset_dir(tmp_path) -> Path:
    """8 places x 3 weathers of training frames (place k at x = 10 k), plus 3 test frames."""
    out = tmp_path / "dataset"
    out.mkdir()
    rng = np.random.default_rng(0)
    patterns = rng.integers(0, 200, (N_PLACES, 16, 16, 3))
    rows, images = [], []
    for place in range(N_PLACES):
        for k, condition in enumerate(CONDITIONS):
            images.append(np.clip(patterns[place] + 25 * k, 0, 255))
            rows.append({"split": "train", "route": "", "drive": "", "condition": condition,
                         "x": 10.0 * place, "y": 0.0, "heading": 0.0, "time": 0.0, "s": np.nan})
    for k, condition in enumerate(CONDITIONS):
        images.append(patterns[0])
        rows.append({"split": "test", "route": "route1", "drive": f"route1/{condition}",
                     "condition": condition, "x": 0.0, "y": 0.0, "heading": 0.0, "time": 0.0,
                     "s": 0.0})
    np.save(out / "images.npy", np.stack(images).astype(np.uint8))
    frames = pd.DataFrame(rows)
    frames.insert(0, "frame", np.arange(len(frames)))
    frames.to_csv(out / "frames.csv", index=False)
    (out / "dataset.json").write_text(json.dumps({
        "kind": "test", "image_size": [16, 16], "conditions": CONDITIONS, "routes": ["route1"],
        "pairs": [["route1", "route1/sunny", "route1/foggy", "sunny-foggy"]], "config": {}}))
    return out


def stage_config(**overrides):
    return OmegaConf.create({"seed": 0, "runtime": {"threads": 1},
                             "models": {"cmal": tiny_config("cmal", **overrides),
                                        "bigan": tiny_config("bigan", **overrides)}})


def test_cmal_stage_writes_model_log_and_samples(tmp_path, dataset_dir):
    out = tmp_path / "models" / "cmal"
    path = train.main(stage_config(), model_name="cmal", dataset_dir=dataset_dir, out_dir=out,
                      checkpoints_dir=tmp_path / "checkpoints" / "cmal")
    assert path == out / "model.pt"
    model, meta = load_trained(out)
    assert meta["conditions"] == CONDITIONS and meta["iteration"] == 4
    assert (out / "train_log.csv").is_file() and list((out / "samples").glob("iter_*.png"))
    assert (tmp_path / "checkpoints" / "cmal" / "last.pt").is_file()
    # Fig. 11 is the report's (cmal_lcd.reports.reconstructions): no reconstructions.npz here
    assert sorted(p.name for p in out.iterdir()) == [
        "dvclive", "model.pt", "samples", "selection.json", "train_log.csv"]


def test_bigan_stage_trains_on_the_training_split_only(tmp_path, dataset_dir):
    out = tmp_path / "bigan"
    train.main(stage_config(), model_name="bigan", dataset_dir=dataset_dir, out_dir=out)
    assert (out / "model.pt").is_file() and (out / "checkpoints" / "last.pt").is_file()
    # 24 training frames, a quarter held out: the fingerprinted data is the training split
    _, meta = load_trained(out)
    assert meta["name"] == "bigan"


def test_stage_is_deterministic(tmp_path, dataset_dir):
    a = train.main(stage_config(), model_name="cmal", dataset_dir=dataset_dir,
                   out_dir=tmp_path / "a")
    b = train.main(stage_config(), model_name="cmal", dataset_dir=dataset_dir,
                   out_dir=tmp_path / "b")
    sa = torch.load(a, weights_only=True)["state_dict"]
    sb = torch.load(b, weights_only=True)["state_dict"]
    assert all(torch.equal(sa[k], sb[k]) for k in sa)


def test_stage_command_line_reads_params_yaml(tmp_path, dataset_dir):
    params = tmp_path / "params.yaml"
    OmegaConf.save(stage_config(), params)
    path = train.cli(["--model", "bigan", "--params", str(params), "--dataset", str(dataset_dir),
                      "--out", str(tmp_path / "m"), "--checkpoints", str(tmp_path / "ck")])
    assert path == tmp_path / "m" / "model.pt" and path.is_file()
    assert (tmp_path / "ck" / "last.pt").is_file()


def test_unknown_model_is_named(tmp_path, dataset_dir):
    with pytest.raises(ValueError, match="model_name"):
        train.main(stage_config(), model_name="vae", dataset_dir=dataset_dir, out_dir=tmp_path)


def test_unknown_condition_in_frames_is_named():
    with pytest.raises(ValueError, match="snowy"):
        train.condition_labels(["sunny", "snowy"], CONDITIONS)


def add_validation_drives(dataset_dir: Path) -> None:
    """Two validation drives over the 8 places (x = 10 k), sunny and foggy."""
    frames = pd.read_csv(dataset_dir / "frames.csv")
    images = np.load(dataset_dir / "images.npy")
    patterns = images[frames["split"].to_numpy() == "train"][::3]  # one sunny frame per place
    rows, extra = [], []
    for k, condition in enumerate(CONDITIONS[:2]):
        for place in range(N_PLACES):
            extra.append(np.clip(patterns[place].astype(int) + 25 * k, 0, 255))
            rows.append({"split": "val", "route": "val", "drive": f"val/{condition}",
                         "condition": condition, "x": 10.0 * place, "y": 0.0, "heading": 0.0,
                         "time": float(place), "s": 10.0 * place})
    val = pd.DataFrame(rows)
    val.insert(0, "frame", np.arange(len(frames), len(frames) + len(val)))
    pd.concat([frames, val]).to_csv(dataset_dir / "frames.csv", index=False)
    np.save(dataset_dir / "images.npy", np.concatenate([images, np.stack(extra)]).astype(np.uint8))
    meta = json.loads((dataset_dir / "dataset.json").read_text())
    meta["validation_pairs"] = [["val", "val/sunny", "val/foggy", "sunny-foggy"]]
    (dataset_dir / "dataset.json").write_text(json.dumps(meta))


def test_validation_drives_are_scored_during_training(tmp_path, dataset_dir):
    add_validation_drives(dataset_dir)
    cfg = stage_config(validate_every=2)
    cfg.matching = {**matching_defaults(), "ds": 2, "v_min": 1.0, "v_max": 1.0, "r_window": 2,
                    "d_thresh": 1, "pose_tolerance": 5.0}
    cfg.features = {"train_frames_per_condition": 4}
    out = tmp_path / "cmal"
    train.main(cfg, model_name="cmal", dataset_dir=dataset_dir, out_dir=out)
    log = pd.read_csv(out / "train_log.csv")
    scored = log.dropna(subset=["val/single_frame_recall_at_1"])
    assert scored["iteration"].tolist() == [0, 2, 4]
    for column in ("val/recall_at_100p", "val/auc_pr", "val/single_frame_recall_at_1"):
        assert scored[column].between(0, 1).all()
