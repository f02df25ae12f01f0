"""The dataset folder: images.npy + frames.csv + dataset.json, saved atomically, loaded fast."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from cmal_lcd.data.store import FRAME_COLUMNS, load_dataset, read_frames, save_dataset


def hand_made(n_train: int = 4) -> tuple[np.ndarray, pd.DataFrame, dict]:
    """Training frames, then two drives along y = 0: ``a`` at x = 0, 2, .., 8 and ``b`` at
    x = 5, 7, .., 13 (its last frames lie beyond ``a``'s end)."""
    rows = [dict(split="train", route="", drive="", condition="sunny", x=float(i), y=50.0,
                 heading=0.0, time=np.nan, s=np.nan) for i in range(n_train)]
    for drive, condition, xs in (("r/sunny", "sunny", np.arange(0, 10, 2.0)),
                                 ("r/foggy", "foggy", np.arange(5, 15, 2.0))):
        rows += [dict(split="test", route="r", drive=drive, condition=condition, x=x, y=0.0,
                      heading=0.0, time=0.1 * k, s=x) for k, x in enumerate(xs)]
    frames = pd.DataFrame(rows)
    frames.insert(0, "frame", np.arange(len(frames)))
    images = np.arange(len(frames) * 4 * 6 * 3, dtype=np.int64).reshape(-1, 4, 6, 3) % 251
    meta = {"kind": "test", "image_size": [4, 6], "conditions": ["sunny", "foggy"],
            "routes": ["r"], "pairs": [["r", "r/sunny", "r/foggy", "sunny-foggy"]]}
    return images.astype(np.uint8), frames, meta


def test_a_saved_dataset_loads_back_identically(tmp_path):
    images, frames, meta = hand_made()
    save_dataset(tmp_path / "ds", images, frames, meta)
    assert sorted(p.name for p in (tmp_path / "ds").iterdir()) == [
        "dataset.json", "frames.csv", "images.npy"]
    ds = load_dataset(tmp_path / "ds")
    assert isinstance(ds.images, np.memmap) and np.array_equal(ds.images, images)
    assert list(ds.frames.columns) == list(FRAME_COLUMNS)
    pd.testing.assert_frame_equal(ds.frames, frames, check_dtype=False)
    assert ds.frames["route"].iloc[0] == "" and np.isnan(ds.frames["s"].iloc[0])
    assert ds.meta == meta


def test_splits_and_drives_select_their_rows(tmp_path):
    images, frames, meta = hand_made()
    ds = load_dataset(save_dataset(tmp_path, images, frames, meta))
    train_images, train = ds.train()
    assert len(train) == 4 and (train["split"] == "train").all()
    assert isinstance(train_images, np.memmap)  # contiguous rows: a view, no copy
    test_images, test = ds.test()
    assert np.array_equal(test_images, images[4:]) and list(test.index) == list(range(10))
    fog_images, fog = ds.drive("r/foggy")
    assert np.array_equal(fog_images, images[9:]) and (fog["condition"] == "foggy").all()
    assert ds.condition_index("foggy") == 1
    with pytest.raises(ValueError, match="name"):
        ds.condition_index("snowy")
    with pytest.raises(ValueError, match="name"):
        ds.drive("r/snowy")


def test_non_contiguous_selection_gathers_the_right_images(tmp_path):
    images, frames, meta = hand_made()
    ds = load_dataset(save_dataset(tmp_path, images, frames, meta))
    mask = np.zeros(len(frames), bool)
    mask[[1, 5, 12]] = True
    selected, rows = ds.select(mask)
    assert np.array_equal(selected, images[[1, 5, 12]])
    assert rows["frame"].tolist() == [1, 5, 12]


def test_ground_truth_between_two_drives_comes_from_poses(tmp_path):
    images, frames, meta = hand_made()
    ds = load_dataset(save_dataset(tmp_path, images, frames, meta))
    # query x = 5, 7, 9, 11, 13 against reference x = 0, 2, 4, 6, 8 (within 1.5 m)
    truth = ds.ground_truth("r/sunny", "r/foggy", max_distance=1.5)
    assert truth.tolist() == [2, 3, 4, -1, -1]


@pytest.mark.parametrize("damage, match", [
    (lambda i, f, m: (i.astype(np.float32), f, m), "uint8"),
    (lambda i, f, m: (i[:-1], f, m), "frame rows"),
    (lambda i, f, m: (i, f.drop(columns="s"), m), "columns"),
    (lambda i, f, m: (i, f.assign(frame=f["frame"] + 1), m), "frame column"),
    (lambda i, f, m: (i, f, {k: v for k, v in m.items() if k != "pairs"}), "pairs"),
    (lambda i, f, m: (i, f, {**m, "conditions": ["sunny"]}), "conditions"),
    (lambda i, f, m: (i, f, {**m, "image_size": [6, 4]}), "image_size"),
])
def test_inconsistent_datasets_are_rejected(tmp_path, damage, match):
    images, frames, meta = damage(*hand_made())
    with pytest.raises(ValueError, match=match):
        save_dataset(tmp_path / "bad", images, frames, meta)
    assert not (tmp_path / "bad" / "images.npy").exists()


def test_a_missing_file_is_named(tmp_path):
    images, frames, meta = hand_made()
    save_dataset(tmp_path, images, frames, meta)
    (tmp_path / "frames.csv").unlink()
    with pytest.raises(FileNotFoundError, match="frames.csv"):
        load_dataset(tmp_path)


def test_frames_csv_keeps_text_and_numbers_apart(tmp_path):
    _, frames, _ = hand_made()
    frames.to_csv(tmp_path / "frames.csv", index=False)
    back = read_frames(tmp_path / "frames.csv")
    assert back["route"].tolist()[:4] == [""] * 4
    assert back["time"].dtype == np.float64 and back["frame"].dtype == np.int64
