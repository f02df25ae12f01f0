"""Precomputed descriptors as a pipeline method (cmal_lcd.features.precomputed): one file per
frame folder, rows = every frame file of the folder in frame order, looked up by the positions
the dataset records for each frame."""

from pathlib import Path

import cv2
import numpy as np
import pytest

from cmal_lcd.data.folders import build_folder_dataset
from cmal_lcd.data.store import load_dataset, save_dataset
from cmal_lcd.features import build_extractor
from cmal_lcd.features.precomputed import DescriptorFolder, MissingDescriptorFile
from cmal_lcd.stages.extract_features import encode_dataset


def write_frames(folder: Path, n: int, seed: int) -> None:
    folder.mkdir(parents=True)
    rng = np.random.default_rng(seed)
    for i in range(n):
        cv2.imwrite(str(folder / f"img-{i + 1:05d}.png"),
                    rng.integers(0, 256, (8, 16, 3), dtype=np.uint8))


@pytest.fixture
def dataset(tmp_path):
    """Summer and winter folders of 10 frames: frames 1-6 train, 7-8 validation, 9-10 test."""
    for season, seed in (("summer", 1), ("winter", 2)):
        write_frames(tmp_path / "frames" / season, 10, seed)
    cfg = {"kind": "folders", "image_size": [8, 16], "root": None, "conditions": None,
           "ground_truth": "index",
           "train": {"dir": str(tmp_path / "frames"), "range": [1, 6], "pattern": None},
           "test": {"dir": str(tmp_path / "frames"), "route": "line", "reference": "summer",
                    "query": "winter", "range": [9, None], "pattern": None},
           "validation": {"range": [7, 8]}}
    images, frames, meta = build_folder_dataset(cfg, seed=0)
    save_dataset(tmp_path / "dataset", images, frames, meta)
    return load_dataset(tmp_path / "dataset")


def descriptor_rows(season_value: float, n: int = 10) -> np.ndarray:
    """Row i = [season, i]: every row says which file and row it came from."""
    return np.stack([np.full(n, season_value), np.arange(n)], axis=1).astype(np.float32)


@pytest.fixture
def descriptors(tmp_path):
    folder = tmp_path / "netvlad"
    folder.mkdir()
    np.save(folder / "summer.npy", descriptor_rows(1.0))
    np.savez(folder / "winter.npz", d=descriptor_rows(2.0))
    return folder


def test_each_frame_gets_the_row_of_its_place_in_its_folder(dataset, descriptors):
    lookup = DescriptorFolder(str(descriptors))
    _, test = dataset.test()
    codes = lookup.codes(dataset.meta["sources"], test["frame"].to_numpy())
    # test frames are files 9 and 10 (rows 8, 9) of summer, then of winter
    assert codes.tolist() == [[1, 8], [1, 9], [2, 8], [2, 9]]
    _, train = dataset.train()
    assert lookup.codes(dataset.meta["sources"], train["frame"].to_numpy()[[0, 5, 6]]).tolist() \
        == [[1, 0], [1, 5], [2, 0]]


def test_the_stage_stores_codes_looked_up_and_refuses_images(dataset, descriptors):
    node = {"_target_": "cmal_lcd.features.precomputed.DescriptorFolder",
            "inputs": str(descriptors), "label": "NetVLAD (precomputed)"}
    extractor = build_extractor("netvlad", conf={"batch_size": 2, "name": "netvlad",
                                                 "extractor": node, "seed": 0})
    arrays = encode_dataset(extractor, dataset, method="netvlad", batch_size=2, per_condition=3)
    assert arrays["codes"][:, 1].tolist() == [8, 9, 8, 9]
    assert arrays["val_codes"][:, 1].tolist() == [6, 7, 6, 7]
    assert arrays["train_codes"].shape == (6, 2) and arrays["train_labels"].tolist() == \
        [0, 0, 0, 1, 1, 1]
    with pytest.raises(ValueError, match="looked up by dataset frame"):
        extractor(np.zeros((1, 8, 16, 3), np.uint8))


def test_without_a_file_for_a_training_folder_there_are_no_training_codes(tmp_path,
                                                                         descriptors):
    for season, seed in (("autumn", 3), ("summer", 1), ("winter", 2)):
        write_frames(tmp_path / "more" / season, 10, seed)
    cfg = {"kind": "folders", "image_size": [8, 16], "root": None, "conditions": None,
           "ground_truth": "index",
           "train": {"dir": str(tmp_path / "more"), "range": [1, 6], "pattern": None},
           "test": {"dir": str(tmp_path / "more"), "route": "line", "reference": "summer",
                    "query": "winter", "range": [9, None], "pattern": None}}
    save_dataset(tmp_path / "ds3", *build_folder_dataset(cfg, seed=0))
    dataset = load_dataset(tmp_path / "ds3")
    lookup = DescriptorFolder(str(descriptors))
    with pytest.raises(MissingDescriptorFile, match=r"no descriptor file for frame folder "
                                                    r"'autumn'"):
        lookup.codes(dataset.meta["sources"], dataset.train()[1]["frame"].to_numpy())
    node = {"_target_": "cmal_lcd.features.precomputed.DescriptorFolder",
            "inputs": str(descriptors)}
    extractor = build_extractor("netvlad", conf={"batch_size": 2, "name": "netvlad",
                                                 "extractor": node, "seed": 0})
    arrays = encode_dataset(extractor, dataset, method="netvlad", batch_size=2, per_condition=3)
    assert arrays["codes"].shape == (4, 2)
    assert arrays["train_codes"].shape == (0, 2) and arrays["train_labels"].shape == (0,)


@pytest.mark.parametrize("broken, message", [
    (lambda d: np.save(d / "summer.npy", descriptor_rows(1.0, n=9)),
     r"summer\.npy: 9 rows, but frame folder .*summer has a frame at position 9"),
    (lambda d: np.save(d / "winter.npy", descriptor_rows(2.0)),
     r"2 descriptor files for folder 'winter'"),
])
def test_broken_descriptor_folders_are_one_line_naming_the_file(dataset, descriptors, broken,
                                                                message):
    broken(descriptors)
    _, test = dataset.test()
    with pytest.raises(ValueError, match=message):
        DescriptorFolder(str(descriptors)).codes(dataset.meta["sources"],
                                                 test["frame"].to_numpy())


def test_a_dataset_without_folders_or_a_missing_folder_is_refused(tmp_path):
    with pytest.raises(ValueError, match="inputs: .* is not a folder"):
        DescriptorFolder(str(tmp_path / "absent"))
    with pytest.raises(ValueError, match="need data.kind: folders"):
        DescriptorFolder(str(tmp_path)).codes([], np.arange(2))
