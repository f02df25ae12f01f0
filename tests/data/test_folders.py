"""A dataset in the store format from folders of real frames (cmal_lcd.data.folders)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import pytest

from cmal_lcd.data.folders import (FolderDatasetError, build_folder_dataset, dark_frame_mask,
                                   main_folders, resolve_folder, select_files)
from cmal_lcd.config import compose
from cmal_lcd.data.frames import FrameReadError
from cmal_lcd.data.store import FRAME_COLUMNS, load_dataset, save_dataset
from cmal_lcd.evaluation import ground_truth_from_correspondence


def write_frames(folder: Path, n: int, *, seed: int, shape=(8, 16), grey=False,
                 start: int = 1) -> list[Path]:
    """``n`` random PNG frames ``img-00001.png ...`` (numbered from ``start``)."""
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    paths = []
    for i in range(start, start + n):
        image = rng.integers(0, 256, shape if grey else shape + (3,), dtype=np.uint8)
        path = folder / f"img-{i:05d}.png"
        assert cv2.imwrite(str(path), image)
        paths.append(path)
    return paths


def config(root: Path, **changes) -> dict:
    """A folders config over ``root`` (train and test in the same season folders)."""
    cfg = {"kind": "folders", "image_size": [8, 16], "root": None, "conditions": None,
           "ground_truth": "index",
           "train": {"dir": str(root), "range": [1, 6], "pattern": None},
           "test": {"dir": str(root), "route": "line", "reference": "summer", "query": "winter",
                    "range": [7, None], "pattern": None}}
    for key, value in changes.items():
        node = cfg
        *parents, leaf = key.split(".")
        for parent in parents:
            node = node[parent]
        node[leaf] = value
    return cfg


@pytest.fixture
def seasons(tmp_path) -> Path:
    write_frames(tmp_path / "summer", 10, seed=1)
    write_frames(tmp_path / "winter", 10, seed=2)
    return tmp_path


def test_training_conditions_are_the_sorted_sub_folders_and_test_is_one_pair(seasons):
    images, frames, meta = build_folder_dataset(config(seasons), seed=0)
    assert images.dtype == np.uint8 and images.shape == (20, 8, 16, 3)
    assert tuple(frames.columns) == FRAME_COLUMNS
    assert meta["kind"] == "folders" and meta["ground_truth"] == "index"
    assert meta["conditions"] == ["summer", "winter"]
    assert meta["routes"] == ["line"]
    assert meta["pairs"] == [["line", "line/summer", "line/winter", "summer-winter"]]
    train = frames[frames["split"] == "train"]
    test = frames[frames["split"] == "test"]
    assert train.groupby("condition").size().to_dict() == {"summer": 6, "winter": 6}
    assert (train["drive"] == "").all() and (train["route"] == "").all()
    assert test.groupby("drive").size().to_dict() == {"line/summer": 4, "line/winter": 4}
    assert frames[["x", "y", "s"]].isna().all().all()  # index ground truth: no poses


def test_frames_are_the_selected_files_in_sorted_order(seasons):
    images, frames, _ = build_folder_dataset(config(seasons), seed=0)
    expected = cv2.imread(str(seasons / "winter" / "img-00007.png"))[:, :, ::-1]
    first_winter_test = frames.index[frames["drive"] == "line/winter"][0]
    np.testing.assert_array_equal(images[first_winter_test], expected)


def test_the_dataset_round_trips_through_the_store(seasons, tmp_path):
    images, frames, meta = build_folder_dataset(config(seasons), seed=0)
    dataset = load_dataset(save_dataset(tmp_path / "out", images, frames, meta))
    test_images, test_frames = dataset.drive("line/winter")
    assert len(test_frames) == 4 and dataset.condition_index("winter") == 1
    np.testing.assert_array_equal(dataset.images, images)


def test_building_twice_gives_identical_datasets(seasons):
    a = build_folder_dataset(config(seasons), seed=0)
    b = build_folder_dataset(config(seasons), seed=0)
    np.testing.assert_array_equal(a[0], b[0])
    pd.testing.assert_frame_equal(a[1], b[1])


def test_overlapping_train_and_test_ranges_are_an_error_naming_the_folder(seasons):
    with pytest.raises(FolderDatasetError, match=r"overlap.*1 frame\(s\) of .*summer"):
        build_folder_dataset(config(seasons, **{"test.range": [6, None]}), seed=0)


def test_separate_test_folders_may_use_every_frame(seasons, tmp_path_factory):
    test_root = tmp_path_factory.mktemp("test")
    write_frames(test_root / "summer", 5, seed=3)
    write_frames(test_root / "winter", 5, seed=4)
    _, frames, _ = build_folder_dataset(
        config(seasons, **{"test.dir": str(test_root), "test.range": None,
                           "train.range": None}), seed=0)
    assert (frames["split"] == "test").sum() == 10 and (frames["split"] == "train").sum() == 20


def test_ranges_are_one_based_inclusive_and_null_last_means_to_the_end(seasons):
    files = sorted((seasons / "summer").glob("*.png"))
    assert [f.name for f in select_files(files, frame_range=[2, 3])] == \
        ["img-00002.png", "img-00003.png"]
    assert len(select_files(files, frame_range=[7, None])) == 4
    assert [f.name for f in select_files(files, pattern="img-0000[13].png")] == \
        ["img-00001.png", "img-00003.png"]


@pytest.mark.parametrize("bad", [[0, 3], [4, 2], [1, 11], [1]])
def test_a_bad_range_is_an_error_naming_the_parameter(seasons, bad):
    with pytest.raises(FolderDatasetError, match=r"data\.train\.range"):
        build_folder_dataset(config(seasons, **{"train.range": bad}), seed=0)


def test_one_condition_folder_is_an_error_for_cmal_naming_the_folder(tmp_path):
    write_frames(tmp_path / "summer", 10, seed=1)
    cfg = config(tmp_path, **{"test.query": "summer"})
    with pytest.raises(FolderDatasetError, match=r"CMAL needs at least two conditions") as err:
        build_folder_dataset(cfg, seed=0)
    assert str(tmp_path) in str(err.value)


def test_a_test_folder_that_is_not_a_training_condition_is_an_error(seasons):
    write_frames(seasons / "autumn", 10, seed=5)
    cfg = config(seasons, conditions=["summer", "winter"], **{"test.query": "autumn"})
    with pytest.raises(FolderDatasetError, match=r"data\.test\.query.*autumn"):
        build_folder_dataset(cfg, seed=0)


def test_configured_conditions_set_the_label_order(seasons):
    _, _, meta = build_folder_dataset(config(seasons, conditions=["winter", "summer"]), seed=0)
    assert meta["conditions"] == ["winter", "summer"]
    with pytest.raises(FolderDatasetError, match=r"data\.conditions.*autumn"):
        build_folder_dataset(config(seasons, conditions=["summer", "autumn"]), seed=0)


def test_a_corrupt_file_is_an_error_naming_the_file(seasons):
    bad = seasons / "winter" / "img-00003.png"
    bad.write_bytes(bad.read_bytes()[:40])
    with pytest.raises(FrameReadError, match="img-00003.png"):
        build_folder_dataset(config(seasons), seed=0)


def test_grey_frames_become_rgb_and_other_sizes_are_resized(tmp_path):
    write_frames(tmp_path / "summer", 10, seed=1, grey=True, shape=(16, 32))
    write_frames(tmp_path / "winter", 10, seed=2, shape=(8, 16))
    images, _, meta = build_folder_dataset(config(tmp_path), seed=0)
    assert images.shape == (20, 8, 16, 3) and meta["image_size"] == [8, 16]
    summer = images[:6]
    assert (summer[..., 0] == summer[..., 1]).all() and (summer[..., 1] == summer[..., 2]).all()


def test_different_frame_counts_make_extra_query_frames_negatives(seasons):
    write_frames(seasons / "winter", 3, seed=6, start=11)  # winter: 13 frames, summer: 10
    _, frames, meta = build_folder_dataset(config(seasons), seed=0)
    n_ref = int((frames["drive"] == "line/summer").sum())
    n_query = int((frames["drive"] == "line/winter").sum())
    assert (n_ref, n_query) == (4, 7)
    assert [d["frames"] for d in meta["drives"]] == [4, 7]
    truth = ground_truth_from_correspondence(n_ref, n_query)
    assert truth.tolist() == [0, 1, 2, 3, -1, -1, -1]


def test_near_black_tunnel_frames_are_kept_and_counted(seasons):
    black = np.zeros((8, 16, 3), np.uint8)
    cv2.imwrite(str(seasons / "summer" / "img-00008.png"), black)
    images, frames, meta = build_folder_dataset(config(seasons), seed=0)
    assert len(frames) == 20
    assert meta["dark_frames"]["test"] == 1 and meta["dark_frames"]["train"] == 0
    assert dark_frame_mask(images).sum() == 1


def test_poses_ground_truth_reads_poses_csv_and_requires_it(seasons):
    cfg = config(seasons, ground_truth="poses")
    with pytest.raises(FolderDatasetError, match=r"poses\.csv"):
        build_folder_dataset(cfg, seed=0)
    for season in ("summer", "winter"):
        names = sorted(p.name for p in (seasons / season).glob("*.png"))
        pd.DataFrame({"name": names, "x": np.arange(10.0) * 2, "y": np.zeros(10)}).to_csv(
            seasons / season / "poses.csv", index=False)
    _, frames, meta = build_folder_dataset(cfg, seed=0)
    assert meta["ground_truth"] == "poses"
    test = frames[frames["drive"] == "line/winter"]
    assert test["x"].tolist() == [12.0, 14.0, 16.0, 18.0]


def test_missing_paths_are_errors_naming_the_parameter(seasons):
    with pytest.raises(FolderDatasetError, match=r"data\.test\.reference"):
        build_folder_dataset(config(seasons, **{"test.reference": "???"}), seed=0)
    with pytest.raises(FolderDatasetError, match=r"data\.train\.dir"):
        build_folder_dataset(config(seasons, **{"train.dir": str(seasons / "nope")}), seed=0)


def test_relative_paths_fall_back_to_the_repository_root(repo_root, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert resolve_folder("conf") == repo_root / "conf"
    (tmp_path / "conf").mkdir()
    assert resolve_folder("conf") == tmp_path / "conf"
    assert resolve_folder("x", root=tmp_path) == tmp_path / "x"


def test_the_dataset_stage_asks_for_two_conditions_only_when_cmal_is_run(tmp_path):
    """On the slice of the config the stage gets (as from DVC and the app): ``methods`` is one
    of its NOT_INPUTS, so it is there to read."""
    from omegaconf import OmegaConf

    from cmal_lcd.stages import config_slice, make_dataset, stage_keys

    def stage_main(cfg):
        part = config_slice(cfg, stage_keys(make_dataset, None, cfg))
        return make_dataset.main(part, out_dir=tmp_path / "out", manifest=None)

    write_frames(tmp_path / "frames" / "summer", 10, seed=1)
    data = config(tmp_path / "frames", **{"test.query": "summer"})
    cfg = OmegaConf.create({"seed": 0, "methods": ["sad", "cmal"], "data": data})
    with pytest.raises(FolderDatasetError, match="CMAL needs at least two"):
        stage_main(cfg)
    cfg = OmegaConf.create({"seed": 0, "methods": ["sad"], "data": data})
    with pytest.raises(FolderDatasetError, match=r"data\.test\.query: the same folder"):
        stage_main(cfg)


def test_main_folders_writes_a_loadable_dataset(seasons, tmp_path_factory):
    from omegaconf import OmegaConf

    out = tmp_path_factory.mktemp("out") / "dataset"
    cfg = OmegaConf.create({"seed": 0, "methods": ["sad", "cmal"], "data": config(seasons)})
    assert main_folders(cfg, out_dir=out, min_conditions=2) == out
    dataset = load_dataset(out)
    assert dataset.meta["kind"] == "folders" and len(dataset) == 20


def test_training_folders_paired_by_index_get_their_position_as_x(seasons):
    _, frames, _ = build_folder_dataset(config(seasons, **{"train.paired_by_index": True}),
                                        seed=0)
    train = frames[frames["split"] == "train"]
    for condition in ("summer", "winter"):
        rows = train[train["condition"] == condition]
        assert rows["x"].tolist() == [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]
        assert (rows["y"] == 0).all()
    assert frames.loc[frames["split"] == "test", ["x", "y"]].isna().all().all()


def test_a_validation_range_makes_validation_drives_of_the_same_folders(seasons):
    cfg = config(seasons, **{"train.range": [1, 4], "test.range": [7, None]})
    cfg["validation"] = {"range": [5, 6]}
    images, frames, meta = build_folder_dataset(cfg, seed=0)
    val = frames[frames["split"] == "val"]
    assert sorted(set(val["drive"])) == ["line_val/summer", "line_val/winter"]
    assert len(val) == 4 and len(frames[frames["split"] == "test"]) == 8
    assert meta["validation_pairs"] == [["line_val", "line_val/summer", "line_val/winter",
                                         "summer-winter"]]
    assert meta["pairs"][0][0] == "line"


@pytest.mark.parametrize("val_range, key", [([5, 7], "data.validation.range / data.test.range"),
                                             ([4, 5], "data.train.range / data.validation.range")])
def test_a_validation_range_overlapping_train_or_test_is_an_error_naming_both_keys(
        seasons, val_range, key):
    cfg = config(seasons, **{"train.range": [1, 4]})
    cfg["validation"] = {"range": val_range}
    with pytest.raises(FolderDatasetError, match=key.replace(".", r"\.")):
        build_folder_dataset(cfg, seed=0)


def test_without_a_validation_range_there_are_no_validation_drives(seasons):
    _, frames, meta = build_folder_dataset(config(seasons), seed=0)
    assert (frames["split"] != "val").all() and meta["validation_pairs"] == []


def test_without_training_frames_the_test_folders_name_the_conditions(seasons):
    images, frames, meta = build_folder_dataset(config(seasons, train=None,
                                                       **{"test.range": None}), seed=0)
    assert meta["conditions"] == ["summer", "winter"]  # reference, then query
    assert (frames["split"] == "test").all() and len(images) == 20
    assert meta["pairs"] == [["line", "line/summer", "line/winter", "summer-winter"]]
    record = {}
    build_folder_dataset(config(seasons, train=None), seed=0, record=record)
    assert record["dirs"] == [seasons]
    # configured conditions must still name both test folders
    with pytest.raises(FolderDatasetError, match=r"data\.test\.query: 'winter'"):
        build_folder_dataset(config(seasons, train=None, conditions=["summer", "autumn"]),
                             seed=0)


def test_train_null_passes_the_schema(seasons):
    from cmal_lcd.schema import validate

    cfg = compose(["data=folders", "data.train=null", f"data.test.dir={seasons}",
                   "data.test.reference=summer", "data.test.query=winter"])
    validate(cfg)
    assert cfg.data.train is None
