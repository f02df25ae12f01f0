"""Stage ``extract_features``: codes of the test frames in ``frames.csv`` order, ``info.json``."""

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch
from omegaconf import OmegaConf

import cmal_lcd.features as features
from cmal_lcd.config import CONF_DIR
from cmal_lcd.features import FeatureExtractor

from cmal_lcd.stages import extract_features  # noqa: E402
from cmal_lcd.features.efficientnet import feature_dim  # noqa: E402

torch.set_num_threads(1)

SPLITS = ["train", "test", "test", "train", "test", "test", "test", "train", "test", "test"]
INFO_KEYS = {"method", "label", "metric", "dim", "dtype", "bytes_per_frame", "n_frames",
             "n_val_frames", "n_train_frames", "weights", "layer_selection"}
TIMING_KEYS = {"batch1_ms", "batched_ms", "batch_size", "repeats", "warmup", "device", "n_frames"}


@pytest.fixture
def dataset_dir(tmp_path) -> Path:
    """A 10-frame dataset in the documented format; frame k is filled with the value 20 k."""
    out = tmp_path / "dataset"
    out.mkdir()
    rng = np.random.default_rng(0)
    images = np.stack([np.clip(20 * k + rng.integers(0, 10, (32, 32, 3)), 0, 255)
                       for k in range(len(SPLITS))]).astype(np.uint8)
    np.save(out / "images.npy", images)
    test = [s == "test" for s in SPLITS]
    frames = pd.DataFrame({
        "frame": np.arange(len(SPLITS)), "split": SPLITS,
        "route": ["route1" if t else "" for t in test],
        "drive": ["route1_sunny" if t else "" for t in test],
        "condition": ["sunny", "rainy", "sunny", "foggy", "sunny", "sunny", "sunny", "rainy",
                      "sunny", "sunny"],
        "x": np.arange(10.0), "y": np.zeros(10), "heading": np.zeros(10),
        "time": np.arange(10.0), "s": [float(i) if t else np.nan for i, t in enumerate(test)],
    })
    frames.to_csv(out / "frames.csv", index=False)
    meta = {"kind": "test", "image_size": [32, 32], "conditions": ["sunny", "rainy", "foggy"],
            "routes": ["route1"], "pairs": [], "config": {}}
    (out / "dataset.json").write_text(json.dumps(meta))
    return out


@pytest.fixture
def cfg():
    """The real config files, with a tiny timing budget and a 16-pixel CMAL."""
    conf = Path(CONF_DIR)
    cfg = OmegaConf.create({
        "seed": 0,
        "runtime": {"threads": 1},
        "features": OmegaConf.load(conf / "features" / "default.yaml"),
        "matching": OmegaConf.load(conf / "matching" / "seqslam.yaml"),
        "models": {"cmal": OmegaConf.load(conf / "model" / "cmal.yaml")},
    })
    # the objective group completes CMAL's loss weights (conf/objective/paper.yaml)
    cfg.models.cmal.loss_weights = OmegaConf.merge(cfg.models.cmal.loss_weights,
                                                   OmegaConf.load(conf / "objective" / "paper.yaml"))
    cfg.features.batch_size = 4
    cfg.features.timing = {"repeats": 1, "warmup": 0, "n_frames": 2}
    cfg.models.cmal.image_size = 16
    return cfg


def register(monkeypatch, name, encode):
    def build(conf, *, model_dir=None, device="cpu"):
        return FeatureExtractor(name=name, label=name.title(), metric="sqeuclidean",
                                weights="none", encode=encode, backend="numpy")

    add_method(monkeypatch, name, build)


def add_method(monkeypatch, name, build):
    """``name``: a method node beside the built-in ones, whose ``build`` is a local function."""
    nodes = {**features.built_in_nodes(),
             name: {"_target_": features.METHOD_TARGET, "build": build, "own_file": "x.py"}}
    monkeypatch.setattr(features, "built_in_nodes", lambda: nodes)


def mean_value(images):
    return images.reshape(len(images), -1).mean(axis=1, keepdims=True).astype(np.float64)


def test_rows_are_the_test_frames_in_file_order(tmp_path, dataset_dir, cfg, monkeypatch):
    register(monkeypatch, "brightness", mean_value)
    out = extract_features.main(cfg, method="brightness", dataset_dir=dataset_dir,
                                models_dir=tmp_path / "models", out_dir=tmp_path / "feat")
    codes = np.load(out / "codes.npy")
    test_frames = [k for k, s in enumerate(SPLITS) if s == "test"]
    assert codes.shape == (len(test_frames), 1) and codes.dtype == np.float32  # float64 -> float32
    np.testing.assert_array_equal(np.floor(codes[:, 0] / 20).astype(int), test_frames)
    # training frames 0 (sunny), 3 (foggy), 7 (rainy) for the centring statistics, with their
    # condition index (sunny 0, rainy 1, foggy 2); no validation frames in this dataset
    train = np.load(out / "train_codes.npy")
    np.testing.assert_array_equal(np.floor(train[:, 0] / 20).astype(int), [0, 3, 7])
    np.testing.assert_array_equal(np.load(out / "train_labels.npy"), [0, 2, 1])
    assert np.load(out / "val_codes.npy").shape == (0, 1)


def test_extractors_are_built_on_the_device_training_uses(tmp_path, dataset_dir, cfg,
                                                          monkeypatch):
    """CUDA when torch sees a GPU, else CPU (cmal_lcd.models.device.pick_device), never a
    hard-coded CPU: a GPU run of experiment=paper once encoded the DNN features on the CPU."""
    import cmal_lcd.models.device as device_module

    seen = []

    def build(conf, *, model_dir=None, device="cpu"):
        seen.append(device)
        return FeatureExtractor(name="probe", label="Probe", metric="sqeuclidean",
                                weights="none", encode=mean_value, backend="numpy")

    add_method(monkeypatch, "probe", build)
    monkeypatch.setattr(device_module, "pick_device", lambda: "cuda:7")
    extract_features.main(cfg, method="probe", dataset_dir=dataset_dir,
                          models_dir=tmp_path / "models", out_dir=tmp_path / "feat")
    assert seen == ["cuda:7"]


def test_dnn_writes_codes_and_info(tmp_path, dataset_dir, cfg, monkeypatch):
    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "empty_torch_home"))
    cfg.features.dnn.batch_size = 3  # the DNN's own batch, not features.batch_size (4)
    out = extract_features.main(cfg, method="dnn", dataset_dir=dataset_dir,
                                models_dir=tmp_path / "models", out_dir=tmp_path / "dnn",
                                timing_path=tmp_path / "timing" / "dnn.json")
    codes = np.load(out / "codes.npy")
    info = json.loads((out / "info.json").read_text())
    timing = json.loads((tmp_path / "timing" / "dnn.json").read_text())
    assert codes.shape == (7, 1792) and codes.dtype == np.float32 and np.isfinite(codes).all()
    assert set(info) == INFO_KEYS and set(timing) == TIMING_KEYS
    assert info["label"] == "DNN (EfficientNet-Lite0, block 10, 4x4, 224 px)"
    assert info["metric"] == "sqeuclidean"
    assert (info["dim"], info["dtype"], info["bytes_per_frame"]) == (1792, "float32", 1792 * 4)
    assert info["n_frames"] == 7 and timing["n_frames"] == 2
    assert timing["batch_size"] == 3 and timing["repeats"] == 1
    assert "1 thread" in timing["device"]


def test_the_timing_of_a_method_without_its_own_batch_uses_features_batch_size(
        tmp_path, dataset_dir, cfg, monkeypatch):
    register(monkeypatch, "flat", mean_value)
    extract_features.main(cfg, method="flat", dataset_dir=dataset_dir, out_dir=tmp_path / "flat",
                          timing_path=tmp_path / "timing.json")
    assert json.loads((tmp_path / "timing.json").read_text())["batch_size"] == 4


def test_sad_stores_float32_thumbnails_from_matching_sad(tmp_path, dataset_dir, cfg):
    out = extract_features.main(cfg, method="sad", dataset_dir=dataset_dir,
                                models_dir=tmp_path / "no_models", out_dir=tmp_path / "sad",
                                timing_path=tmp_path / "sad_timing.json")
    info = json.loads((out / "info.json").read_text())
    timing = json.loads((tmp_path / "sad_timing.json").read_text())
    width, height = cfg.matching.sad.width, cfg.matching.sad.height
    assert (info["label"], info["metric"], info["dtype"]) == ("SAD", "sad", "float32")
    assert info["dim"] == width * height and info["bytes_per_frame"] == width * height * 4
    assert np.load(out / "codes.npy").shape == (7, width * height)
    assert "numpy" in timing["device"]


def test_timings_go_apart_so_the_codes_folder_is_the_same_on_every_run(tmp_path, dataset_dir,
                                                                        cfg):
    """The codes folder (every later stage's input) holds nothing that differs between two
    runs of the same config; the timings, which do, are in their own file."""
    def run(name):
        out = extract_features.main(cfg, method="sad", dataset_dir=dataset_dir,
                                    models_dir=tmp_path / "no_models", out_dir=tmp_path / name,
                                    timing_path=tmp_path / f"{name}.json")
        return {p.name: p.read_bytes() for p in sorted(out.iterdir())}

    first, second = run("first"), run("second")
    assert first == second and "info.json" in first
    assert b"batch1_ms" not in first["info.json"]
    assert "batch1_ms" in json.loads((tmp_path / "first.json").read_text())


def test_untrained_control_needs_no_model_file_and_is_reproducible(tmp_path, dataset_dir, cfg):
    first = extract_features.main(cfg, method="cmal_untrained", dataset_dir=dataset_dir,
                                  models_dir=tmp_path / "no_models", out_dir=tmp_path / "a")
    second = extract_features.main(cfg, method="cmal_untrained", dataset_dir=dataset_dir,
                                   models_dir=tmp_path / "no_models", out_dir=tmp_path / "b")
    info = json.loads((first / "info.json").read_text())
    assert (info["label"], info["dim"], info["bytes_per_frame"]) == ("CMAL (untrained control)", 1024, 4096)
    np.testing.assert_array_equal(np.load(first / "codes.npy"), np.load(second / "codes.npy"))


def test_nonfinite_codes_fail_naming_method_and_frame_and_write_nothing(tmp_path, dataset_dir, cfg,
                                                                       monkeypatch):
    def encode(images):
        codes = np.ones((len(images), 2), np.float32)
        codes[(images.reshape(len(images), -1).mean(axis=1) // 20) == 4] = np.nan  # frame 4
        return codes

    register(monkeypatch, "broken", encode)
    with pytest.raises(ValueError, match=r"broken: .*test row 2"):  # frame 4 is test row 2
        extract_features.main(cfg, method="broken", dataset_dir=dataset_dir,
                              models_dir=tmp_path, out_dir=tmp_path / "broken")
    assert not (tmp_path / "broken").exists() or not any((tmp_path / "broken").iterdir())


def test_command_line_reads_params_yaml(tmp_path, dataset_dir, cfg, monkeypatch):
    register(monkeypatch, "brightness", mean_value)
    params = tmp_path / "params.yaml"
    OmegaConf.save(cfg, params)
    out = extract_features.cli(["--method", "brightness", "--params", str(params), "--dataset",
                                str(dataset_dir), "--out", str(tmp_path / "cli"),
                                "--timing", str(tmp_path / "timing.json")])
    assert out == tmp_path / "cli"
    assert json.loads((out / "info.json").read_text())["method"] == "brightness"
    assert json.loads((tmp_path / "timing.json").read_text())["n_frames"] == 2


def test_command_line_rejects_unknown_methods(tmp_path, dataset_dir, cfg):
    params = tmp_path / "params.yaml"
    OmegaConf.save(cfg, params)
    with pytest.raises(ValueError, match=r"unknown feature method 'vlad'"):
        extract_features.cli(["--method", "vlad", "--params", str(params), "--dataset",
                              str(dataset_dir), "--out", str(tmp_path / "vlad")])
    assert not (tmp_path / "vlad").exists()


def add_validation_drives(dataset_dir: Path, cfg) -> None:
    """Two validation drives of 15 places each (sunny, and a darker rainy copy) appended to
    the tiny dataset; SeqSLAM's ds set to 4 to fit them."""
    frames = pd.read_csv(dataset_dir / "frames.csv")
    images = np.load(dataset_dir / "images.npy")
    rng = np.random.default_rng(1)
    places = rng.integers(0, 255, (15, 32, 32, 3))
    val = pd.DataFrame({"frame": len(frames) + np.arange(30), "split": "val", "route": "val",
                        "drive": ["val/sunny"] * 15 + ["val/rainy"] * 15,
                        "condition": ["sunny"] * 15 + ["rainy"] * 15,
                        "x": np.tile(np.arange(15.0) * 10, 2), "y": 0.0, "heading": 0.0,
                        "time": np.tile(np.arange(15.0), 2), "s": np.tile(np.arange(15.0), 2)})
    pd.concat([frames, val]).to_csv(dataset_dir / "frames.csv", index=False)
    np.save(dataset_dir / "images.npy", np.concatenate(
        [images, places.astype(np.uint8), (places * 0.7 + 30).astype(np.uint8)]))
    meta = json.loads((dataset_dir / "dataset.json").read_text())
    meta["validation_pairs"] = [["val", "val/sunny", "val/rainy", "sunny-rainy"]]
    (dataset_dir / "dataset.json").write_text(json.dumps(meta))
    cfg.matching.ds = 4


def test_dnn_layer_is_chosen_on_the_validation_drives_and_recorded(tmp_path, dataset_dir, cfg,
                                                                    monkeypatch):
    from cmal_lcd.features.dnn import candidate_pairs, dnn_settings

    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "empty_torch_home"))
    add_validation_drives(dataset_dir, cfg)
    out = extract_features.main(cfg, method="dnn", dataset_dir=dataset_dir,
                                models_dir=tmp_path / "models", out_dir=tmp_path / "dnn")
    info = json.loads((out / "info.json").read_text())
    selection = info["layer_selection"]
    assert [(row["image_size"], row["layer"]) for row in selection["candidates"]] == \
        candidate_pairs(dnn_settings(OmegaConf.to_container(cfg.features)))
    best = max(row["val/recall_at_100p"] for row in selection["candidates"])
    chosen = next(r for r in selection["candidates"]
                  if (r["layer"], r["image_size"]) == (selection["selected"],
                                                        selection["image_size"]))
    assert chosen["val/recall_at_100p"] == best
    block = int(selection["selected"].removeprefix("block"))
    assert f"block {block}, 4x4, {selection['image_size']} px" in info["label"]
    assert np.load(out / "codes.npy").shape[1] == info["dim"] == feature_dim(
        selection["selected"], (4, 4))
    assert np.load(out / "val_codes.npy").shape == (30, info["dim"])


@pytest.mark.parametrize("method", ["dnn", "dnn_head"])
def test_the_layer_choices_codes_are_stored_bit_for_bit_as_the_chosen_extractor_encodes(
        tmp_path, dataset_dir, cfg, monkeypatch, method):
    """The validation and centring codes come from the layer choice's own pass (not encoded a
    second time): they must equal what the chosen extractor gives for those frames."""
    from cmal_lcd.data.store import load_dataset
    from cmal_lcd.features.dnn import layer_overrides
    from cmal_lcd.matching.normalise import centring_sample

    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "empty_torch_home"))
    add_validation_drives(dataset_dir, cfg)
    cfg.features.dnn.image_size_candidates = [96, 64]
    out = extract_features.main(cfg, method=method, dataset_dir=dataset_dir,
                                models_dir=tmp_path / "models", out_dir=tmp_path / method)
    selection = json.loads((out / "info.json").read_text())["layer_selection"]
    conf = features.extractor_conf(cfg, method)
    conf["dnn"] = {**conf["dnn"], **layer_overrides(selection)}
    extractor = features.build_extractor(method, conf=conf)
    dataset = load_dataset(dataset_dir)
    val_images, _ = dataset.validation()
    train_images, train_frames = dataset.train()
    rows, _ = centring_sample(dataset.conditions, train_frames["condition"],
                              per_condition=int(conf["train_frames_per_condition"]))
    assert len(val_images) and len(rows)
    assert np.array_equal(np.load(out / "val_codes.npy"), extractor(val_images))
    assert np.array_equal(np.load(out / "train_codes.npy"), extractor(train_images[rows]))


def test_the_pooled_heads_input_side_is_chosen_on_the_validation_drives(tmp_path, dataset_dir,
                                                                        cfg, monkeypatch):
    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "empty_torch_home"))
    add_validation_drives(dataset_dir, cfg)
    cfg.features.dnn.image_size_candidates = [96, 64]
    cfg.features.dnn.layer_candidates = ["block4"]  # (dnn's; checked against the sides)
    out = extract_features.main(cfg, method="dnn_head", dataset_dir=dataset_dir,
                                models_dir=tmp_path / "models", out_dir=tmp_path / "dnn_head")
    info = json.loads((out / "info.json").read_text())
    selection = info["layer_selection"]
    assert [(row["image_size"], row["layer"]) for row in selection["candidates"]] == [
        (96, "head"), (64, "head")]
    assert selection["selected"] == "head"
    scores = {row["image_size"]: row["val/recall_at_100p"] for row in selection["candidates"]}
    assert scores[selection["image_size"]] == max(scores.values())
    assert info["label"] == f"DNN (EfficientNet-Lite0, pooled head, {selection['image_size']} px)"
    assert np.load(out / "codes.npy").shape[1] == info["dim"] == 1280


def test_encoding_reports_progress_in_frames_and_gives_the_codes_of_one_call(caplog,
                                                                           monkeypatch):
    """Steps of whole batches: the extractor sees the batches a single call would, so the
    codes are the same; without a terminal, a line per interval names the frames done."""
    import logging

    import cmal_lcd.progress as progress

    monkeypatch.setattr(progress, "LOG_INTERVAL_S", 0.0)  # a line after every step
    import cmal_lcd.features.base as base

    monkeypatch.setattr(base, "BATCHES_PER_STEP", 2)
    calls = []

    def encode(images):
        calls.append(len(images))
        return images.reshape(len(images), -1)[:, :3].astype(np.float32)

    extractor = FeatureExtractor(name="probe", label="Probe", metric="sqeuclidean",
                                 weights="none", encode=encode, backend="numpy")
    images = np.random.default_rng(0).integers(0, 255, (11, 4, 4, 3), dtype=np.uint8)
    with caplog.at_level(logging.INFO, logger="cmal_lcd.stages.extract_features"):
        codes = base.encode_with_progress(extractor, images, batch_size=3,
                                          desc="probe: encode test frames",
                                          logger=extract_features.logger)
    np.testing.assert_array_equal(codes, extractor(images))
    assert calls[:3] == [6, 5, 11]  # two steps of two batches of 3, then the reference call
    lines = [r.getMessage().split(",")[0] for r in caplog.records]
    assert lines == ["probe: encode test frames: 6/11 frames (55%)",
                     "probe: encode test frames: 11/11 frames (100%)"]


def test_a_method_node_of_yours_chooses_on_validation_as_dnn_does(tmp_path, dataset_dir, cfg,
                                                                 monkeypatch):
    """A ``cmal_lcd.features.Method`` node (the form of the built-in nodes) gives a method of
    yours their capabilities: its ``choose`` runs on the dataset, its ``apply_choice`` builds
    the chosen extractor, and the choice is recorded in ``info.json``."""
    seen = []

    def choose(cfg, conf, dataset, *, device, method):
        seen.append((method, sorted(dataset.meta["conditions"])))
        return {"selected": "double", "candidates": [{"scale": 1.0}, {"scale": 2.0}]}, {}

    def build(conf, *, model_dir=None, device="cpu"):
        scale = conf.get("scale", 1.0)
        return FeatureExtractor(name="scaled", label="Scaled", metric="sqeuclidean",
                                weights="none", encode=lambda im: scale * mean_value(im),
                                backend="numpy")

    nodes = {**features.built_in_nodes(), "scaled": {
        "_target_": features.METHOD_TARGET, "build": build, "own_file": "x.py",
        "choose": choose, "apply_choice": lambda conf, choice: {**conf, "scale": 2.0}}}
    monkeypatch.setattr(features, "built_in_nodes", lambda: nodes)
    out = extract_features.main(cfg, method="scaled", dataset_dir=dataset_dir,
                                models_dir=tmp_path / "models", out_dir=tmp_path / "feat")
    assert seen == [("scaled", ["foggy", "rainy", "sunny"])]
    info = json.loads((out / "info.json").read_text())
    assert info["layer_selection"]["selected"] == "double"
    codes = np.load(out / "codes.npy")
    test_frames = [k for k, s in enumerate(SPLITS) if s == "test"]
    np.testing.assert_array_equal(np.floor(codes[:, 0] / 40).astype(int), test_frames)
