"""Nordland convention presets (conf/nordland/, conf/data/nordland_full.yaml) and the manifest
of the shared sample."""

from __future__ import annotations

from pathlib import Path

import pytest
from omegaconf import OmegaConf

from cmal_lcd.config import compose
from cmal_lcd.data.folders import select_files
from cmal_lcd.data.manifest import read_manifest, verify_manifest


@pytest.mark.parametrize("direction, reference, query", [("summer_to_winter", "summer", "winter"),
                                                         ("winter_to_summer", "winter", "summer")])
@pytest.mark.parametrize("tolerance, frames", [("pm1", 1), ("pm2", 2), ("pm10", 10)])
def test_direction_and_tolerance_presets_compose(direction, reference, query, tolerance, frames):
    cfg = compose(["experiment=nordland", f"+nordland/direction={direction}",
                   f"+nordland/tolerance={tolerance}"])
    assert (cfg.data.test.reference, cfg.data.test.query) == (reference, query)
    assert cfg.matching.d_thresh == frames
    assert cfg.data.train.range == [1, 1000]  # nothing else moves


def full_copy_selection(cfg, key):
    """Names selected from a simulated full season folder images-00001 .. images-35768."""
    files = [Path("summer") / f"images-{i:05d}.png" for i in range(1, 35769)]
    node = cfg.data[key]
    pattern = node.get("pattern") if key != "validation" else cfg.data.test.pattern
    return [f.name for f in select_files(files, frame_range=list(node.range), pattern=pattern)]


def test_full_copy_preset_selects_the_shared_sample_frames():
    cfg = compose(["experiment=nordland", "data=nordland_full", "data.train.dir=/x",
                   "data.test.dir=/x"])
    expected = {"train": range(10, 10001, 10), "validation": range(10010, 12001, 10),
                "test": range(12010, 18001, 10)}
    for key, numbers in expected.items():
        assert full_copy_selection(cfg, key) == [f"images-{i:05d}.png" for i in numbers], key


@pytest.mark.nordland
def test_full_copy_preset_equals_the_sample_split_by_name(nordland_dir):
    sample = compose(["experiment=nordland"]).data
    full = compose(["experiment=nordland", "data=nordland_full", "data.train.dir=/x",
                    "data.test.dir=/x"])
    names = sorted(p.name for p in (nordland_dir / "summer").glob("*.png"))
    for key in ("train", "validation", "test"):
        first, last = sample[key].range
        assert full_copy_selection(full, key) == names[first - 1:last], key


@pytest.mark.nordland
def test_shared_sample_manifest_verifies_and_follows_the_direction(nordland_dir, tmp_path):
    from cmal_lcd.stages import make_dataset

    cfg = compose(["experiment=nordland", "+nordland/direction=winter_to_summer",
                   f"data.train.dir={nordland_dir}", f"data.test.dir={nordland_dir}"])
    cfg = OmegaConf.merge(cfg, {"methods": ["sad"]})
    make_dataset.main(cfg, out_dir=tmp_path / "dataset", manifest=tmp_path / "manifest.csv")
    manifest = read_manifest(tmp_path / "manifest.csv")
    test = manifest[manifest["split"] == "test"]
    assert set(test.loc[test["role"] == "reference", "condition"]) == {"winter"}
    assert test["path"].iloc[0] == "winter/images-12010.png"
    assert manifest.groupby("split").size().to_dict() == {"train": 2000, "val": 400,
                                                          "test": 1200}
    assert verify_manifest(manifest, nordland_dir).ok
    assert verify_manifest(manifest, tmp_path / "dataset").ok
