"""The dataset and calibration stages on a tiny world: files, contents, byte-determinism."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from omegaconf import OmegaConf

from cmal_lcd.data.store import load_dataset
from cmal_lcd.stages import calibrate_world, make_dataset

TINY_WORLD = Path(__file__).resolve().parents[1] / "data" / "tiny_world.yaml"


def tiny_cfg():
    """The composed config with the tiny world of ``tests/data/tiny_world.yaml``."""
    from cmal_lcd.config import compose

    plain = OmegaConf.to_container(compose(), resolve=True)
    for key, value in yaml.safe_load(TINY_WORLD.read_text()).items():
        if isinstance(value, dict):
            plain["data"][key].update(value)
        else:
            plain["data"][key] = value
    return OmegaConf.create(plain)


@pytest.fixture(scope="module")
def dataset_dir(tmp_path_factory) -> Path:
    return make_dataset.main(tiny_cfg(), out_dir=tmp_path_factory.mktemp("run") / "dataset")


def test_the_stage_writes_a_complete_dataset(dataset_dir):
    ds = load_dataset(dataset_dir)
    cfg = tiny_cfg()
    assert ds.images.shape[1:] == (16, 16, 3)
    assert ds.meta["conditions"] == ["sunny", "foggy", "rainy"]
    assert ds.meta["routes"] == ["route1", "route2"]
    assert ds.meta["ground_truth"] == "poses"
    assert [p[3] for p in ds.meta["pairs"]] == ["foggy-rainy", "foggy-sunny", "rainy-sunny"] * 2
    assert ds.meta["pairs"][0] == ["route1", "route1/foggy", "route1/rainy", "foggy-rainy"]
    assert ds.meta["seed"] == cfg.seed and ds.meta["config"]["train_per_condition"] == 3
    train_images, train = ds.train()
    assert len(train) == 9 and train_images.std() > 10  # rendered, not blank
    for route, ref, query, _ in ds.meta["pairs"]:
        assert len(ds.drive(ref)[1]) > 20 and len(ds.drive(query)[1]) > 20


def test_same_params_give_the_same_bytes(dataset_dir, tmp_path):
    again = make_dataset.main(tiny_cfg(), out_dir=tmp_path / "again")
    for name in ("images.npy", "frames.csv", "dataset.json"):
        assert (again / name).read_bytes() == (dataset_dir / name).read_bytes(), name


def test_the_command_line_reads_params_yaml(tmp_path):
    cfg = tiny_cfg()
    cfg.data.train_per_condition = 1
    cfg.data.test.routes = {"route1": dict(cfg.data.test.routes.route1)}
    params = tmp_path / "params.yaml"
    OmegaConf.save(cfg, params)
    make_dataset.cli(["--params", str(params), "--out", str(tmp_path / "ds")])
    ds = load_dataset(tmp_path / "ds")
    assert (ds.frames["split"] == "train").sum() == 3 and ds.meta["routes"] == ["route1"]


def test_calibration_reports_cross_and_same_weather_difficulty(dataset_dir, tmp_path):
    out = calibrate_world.main(tiny_cfg(), dataset_dir=dataset_dir, out_dir=tmp_path / "world")
    report = json.loads((out / "difficulty.json").read_text())
    assert set(report["routes"]) == {"route1", "route2"}
    pairs = report["routes"]["route1"]
    assert len(pairs) == 6 and "foggy-rainy" in pairs
    for pair in pairs.values():
        for kind in ("cross", "same"):
            assert 0.0 <= pair[kind]["sf_recall_at_1"] <= 1.0
            assert 0.0 <= pair[kind]["recall_at_100p"] <= 1.0
    assert isinstance(report["summary"]["ok"], bool)
    text = (out / "difficulty.md").read_text()
    assert "## route1" in text and "foggy-rainy" in text
    assert np.isfinite(report["summary"]["route1"]["cross_recall_at_1"])


@pytest.mark.parametrize("function", ["plot_weather_samples", "plot_world_map"])
def test_world_figures_are_written_as_png_and_byte_stable_pdf(dataset_dir, tmp_path, function):
    from cmal_lcd.reports import world_figures

    ds = load_dataset(dataset_dir)
    plot = getattr(world_figures, function)
    png = plot(ds, tmp_path / "figure.png")
    pdf = plot(ds, tmp_path / "figure.pdf")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and pdf.read_bytes()[:5] == b"%PDF-"
    first = pdf.read_bytes()
    assert plot(ds, tmp_path / "figure.pdf").read_bytes() == first
    with pytest.raises(ValueError, match="path"):
        plot(ds, tmp_path / "figure.jpg")


def test_calibration_skips_datasets_that_are_not_the_weather_world(dataset_dir, tmp_path):
    import shutil

    copy = tmp_path / "folders"
    shutil.copytree(dataset_dir, copy)
    meta = json.loads((copy / "dataset.json").read_text())
    meta["kind"] = "folders"
    (copy / "dataset.json").write_text(json.dumps(meta))
    out = calibrate_world.main(tiny_cfg(), dataset_dir=copy, out_dir=tmp_path / "world")
    assert "skipped" in json.loads((out / "difficulty.json").read_text())
