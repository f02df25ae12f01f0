"""Stage ``select_protocol``: a method's protocol is chosen on validation drives only."""

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from omegaconf import OmegaConf

from cmal_lcd.config import CONF_DIR
from cmal_lcd.stages import select_protocol

N_PLACES, DIM = 80, 16


def write_dataset(root: Path, rng) -> tuple[Path, pd.DataFrame]:
    """Training frames (two weathers), a test route and a validation route (two drives each)."""
    rows = [dict(split="train", route="", drive="", condition=c, x=np.nan, y=np.nan)
            for c in ("sunny", "foggy") for _ in range(30)]
    for split, route in (("test", "route1"), ("val", "val")):
        for condition in ("sunny", "foggy"):
            rows += [dict(split=split, route=route, drive=f"{route}/{condition}",
                          condition=condition, x=float(i) * 2.0, y=0.0)
                     for i in range(N_PLACES)]
    frames = pd.DataFrame(rows)
    frames.insert(0, "frame", np.arange(len(frames)))
    frames["heading"], frames["time"], frames["s"] = 0.0, np.nan, np.nan
    out = root / "dataset"
    out.mkdir(parents=True)
    np.save(out / "images.npy", np.zeros((len(frames), 8, 8, 3), np.uint8))
    frames.to_csv(out / "frames.csv", index=False)
    pair = lambda r: [r, f"{r}/sunny", f"{r}/foggy", "sunny-foggy"]  # noqa: E731
    meta = {"kind": "test", "image_size": [8, 8], "conditions": ["sunny", "foggy"],
            "routes": ["route1"], "pairs": [pair("route1")], "validation_routes": ["val"],
            "validation_pairs": [pair("val")], "ground_truth": "poses", "config": {}}
    (out / "dataset.json").write_text(json.dumps(meta))
    return out, frames


def write_features(root: Path, frames: pd.DataFrame, rng, *, test_codes=None) -> Path:
    """Codes = smooth place signal + a large per-weather offset (the failure of raw codes)."""
    offsets = {"sunny": rng.normal(size=DIM) * 30, "foggy": rng.normal(size=DIM) * 30}
    places = np.cumsum(rng.normal(size=(N_PLACES, DIM)), axis=0)

    def codes(split):
        part = frames[frames["split"] == split]
        out = []
        for _, row in part.iterrows():
            place = places[int(row["x"] / 2)] if split != "train" else rng.normal(size=DIM)
            out.append(place + offsets[row["condition"]] + 0.3 * rng.normal(size=DIM))
        return np.asarray(out, np.float32)

    out = root / "features"
    out.mkdir()
    train = frames[frames["split"] == "train"]
    test = codes("test")  # drawn either way, so the validation codes are the same
    np.save(out / "codes.npy", test if test_codes is None else test_codes)
    np.save(out / "val_codes.npy", codes("val"))
    np.save(out / "train_codes.npy", codes("train"))
    np.save(out / "train_labels.npy", (train["condition"] == "foggy").to_numpy(np.int64))
    (out / "info.json").write_text(json.dumps({"method": "m", "label": "M", "metric":
                                               "sqeuclidean", "dim": DIM, "bytes_per_frame": 64}))
    return out


@pytest.fixture
def cfg():
    matching = OmegaConf.load(Path(CONF_DIR) / "matching" / "seqslam.yaml")
    matching.ds = 5
    matching.d_thresh = 2
    matching.pose_tolerance = 1.5
    matching.protocol.enhance_windows = [10]
    return OmegaConf.create({"matching": matching})


def run(cfg, tmp_path, **kw):
    rng = np.random.default_rng(0)
    dataset, frames = write_dataset(tmp_path, rng)
    features = write_features(tmp_path, frames, rng, **kw)
    out = select_protocol.main(cfg, method="m", dataset_dir=dataset, features_dir=features,
                               out_path=tmp_path / "protocol" / "m.json")
    return json.loads(out.read_text())


def test_weather_offsets_make_it_choose_a_centred_protocol_over_the_papers(cfg, tmp_path):
    record = run(cfg, tmp_path)
    assert record["selected"]["centre"] in ("reference", "condition")
    assert record["validation_pairs"] == [["val", "val/sunny", "val/foggy", "sunny-foggy"]]
    scores = {c["label"]: c["mean_recall_at_100p"] for c in record["candidates"]}
    assert len(scores) == 3 * 2 * 2
    assert scores[record["selected"]["label"]] == max(scores.values())
    assert scores[record["selected"]["label"]] > scores[record["paper"]["label"]]


def test_test_codes_are_never_read(cfg, tmp_path):
    first = run(cfg, tmp_path / "a")
    noise = np.random.default_rng(9).normal(size=(2 * N_PLACES, DIM)).astype(np.float32)
    second = run(cfg, tmp_path / "b", test_codes=noise)
    assert first["selected"] == second["selected"]
    assert first["candidates"] == second["candidates"]


def test_without_validation_drives_it_falls_back_to_the_paper_protocol_and_says_so(cfg,
                                                                                   tmp_path):
    rng = np.random.default_rng(0)
    dataset, frames = write_dataset(tmp_path, rng)
    meta = json.loads((dataset / "dataset.json").read_text())
    meta["validation_pairs"] = []
    (dataset / "dataset.json").write_text(json.dumps(meta))
    features = write_features(tmp_path, frames, rng)
    record = json.loads(select_protocol.main(cfg, method="m", dataset_dir=dataset,
                                             features_dir=features,
                                             out_path=tmp_path / "m.json").read_text())
    assert record["selected"] == record["paper"]
    assert "no validation drives" in record["fallback"]


def test_an_unknown_protocol_key_is_refused_at_composition_naming_it():
    """The schema (cmal_lcd.schema.ProtocolSchema) refuses it before any stage runs."""
    from cmal_lcd.config import compose

    with pytest.raises(ValueError, match=r"matching\.protocol\.windows"):
        compose(["+matching.protocol.windows=[5]"])
