"""Catalogue: condition labels and ground truth (docs/reliability.md, "Labels and ground truth").

Unknown conditions are rejected where they enter (Hydra override, `data` config, dataset store,
training labels) with a message naming the condition and the known ones. `poses.csv` problems
are rejected naming the file and line. Reference and query of different lengths are handled.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from cmal_lcd.config import compose
from cmal_lcd.data.frames import FrameReadError, read_poses
from cmal_lcd.data.store import FRAME_COLUMNS, save_dataset
from cmal_lcd.data.world.config import DataConfig
from cmal_lcd.evaluation import (
    ground_truth_from_correspondence,
    ground_truth_from_poses,
    loop_closure_metrics,
)
from cmal_lcd.matching import SeqSLAMParams, match_sequences
from cmal_lcd.stages.train import condition_labels

# ---------------------------------------------------------------- unknown condition name


def test_unknown_condition_in_a_pair_names_the_key_and_the_known_conditions():
    cfg = compose(["debug=tiny", "data.test.pairs=[[foggy,snowy]]"])
    with pytest.raises(ValueError, match=r"data\.test\.pairs: unknown condition 'snowy'.*"
                                         r"known: \['sunny', 'foggy', 'rainy'\]"):
        DataConfig.from_config(cfg.data)


def test_unknown_condition_config_group_is_named_by_hydra():
    from hydra.errors import MissingConfigException

    with pytest.raises(MissingConfigException, match="condition/snowy"):
        compose(["debug=tiny", "+condition@data.conditions.snowy=snowy"])


def test_removing_a_condition_that_other_keys_use_names_the_key():
    cfg = compose(["debug=tiny", "~condition@data.conditions.foggy"])
    with pytest.raises(ValueError, match=r"data\.test\.windows\.foggy: unknown condition"):
        DataConfig.from_config(cfg.data)


def test_frame_labelled_with_an_unknown_condition_is_refused_by_the_store(tmp_path):
    images = np.zeros((2, 4, 4, 3), np.uint8)
    frames = pd.DataFrame({c: [np.nan, np.nan] for c in FRAME_COLUMNS})
    frames["frame"] = [0, 1]
    frames["split"] = ["train", "train"]
    frames["route"] = ["", ""]
    frames["drive"] = ["", ""]
    frames["condition"] = ["sunny", "snowy"]
    meta = {"conditions": ["sunny"], "routes": [], "pairs": [], "image_size": [4, 4]}
    with pytest.raises(ValueError, match=r"conditions not in meta: \['snowy'\]"):
        save_dataset(tmp_path / "ds", images, frames, meta)
    assert not (tmp_path / "ds" / "dataset.json").exists()


def test_training_label_of_an_unknown_condition_names_it():
    with pytest.raises(ValueError, match=r"condition: \['snowy'\] not in dataset.json"):
        condition_labels(["sunny", "snowy"], ["sunny", "foggy"])


# ------------------------------------------- a condition with no frames; one condition only

def _tiny_training(tmp_path, *, conditions, labels):
    import torch

    from cmal_lcd.models import train_model

    torch.set_num_threads(1)
    cfg = compose(["debug=tiny", "models.cmal.iterations=1"]).models.cmal
    images = np.random.default_rng(0).integers(0, 256, (len(labels), 32, 32, 3), np.uint8)
    return train_model("cmal", cfg, images, np.asarray(labels), conditions=conditions,
                       out_dir=tmp_path / "cmal", seed=0)


def test_cmal_training_refuses_a_condition_without_frames(tmp_path):
    with pytest.raises(ValueError, match=r"conditions.*'c'"):
        _tiny_training(tmp_path, conditions=["a", "b", "c"], labels=np.arange(16) % 2)


def test_cmal_training_refuses_a_single_condition(tmp_path):
    with pytest.raises(ValueError, match=r"conditions.*at least 2"):
        _tiny_training(tmp_path, conditions=["a"], labels=np.zeros(16, np.int64))


def test_bigan_does_not_need_conditions_and_trains_on_one(tmp_path):
    import torch

    from cmal_lcd.models import train_model

    torch.set_num_threads(1)
    cfg = compose(["debug=tiny", "models.bigan.iterations=1"]).models.bigan
    images = np.random.default_rng(0).integers(0, 256, (16, 32, 32, 3), np.uint8)
    path = train_model("bigan", cfg, images, np.zeros(16, np.int64), conditions=["a"],
                       out_dir=tmp_path / "bigan", seed=0)
    assert path.is_file()


# ------------------------------------------------------------------------- poses.csv

NAMES = ["f0.png", "f1.png", "f2.png"]


def write_poses(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "poses.csv"
    path.write_text(text)
    return path


def test_poses_with_a_missing_row_name_the_first_frame_without_pose(tmp_path):
    path = write_poses(tmp_path, "name,x,y\nf0.png,0,0\nf2.png,2,0\n")
    with pytest.raises(FrameReadError, match=re.escape(str(path)) + r".*no pose for 1.*f1\.png"):
        read_poses(path, NAMES)


def test_poses_with_nan_position_name_the_line_and_column(tmp_path):
    path = write_poses(tmp_path, "name,x,y\nf0.png,0,0\nf1.png,,0\nf2.png,2,0\n")
    with pytest.raises(FrameReadError, match=re.escape(str(path)) + r".*line 3: x"):
        read_poses(path, NAMES)


def test_poses_with_a_duplicate_frame_name_both_lines(tmp_path):
    path = write_poses(tmp_path, "name,x,y\nf0.png,0,0\nf1.png,1,0\nf1.png,1,0\nf2.png,2,0\n")
    with pytest.raises(FrameReadError, match=r"line 4: duplicate row for frame f1\.png .*line 3"):
        read_poses(path, NAMES)


def test_nan_timestamps_are_kept_as_nan(tmp_path):
    """``time`` is informational (ground truth uses x, y only): a missing one stays NaN."""
    path = write_poses(tmp_path, "name,x,y,time\nf0.png,0,0,0.0\nf1.png,1,0,\nf2.png,2,0,1.0\n")
    poses = read_poses(path, NAMES)
    assert np.isnan(poses["time"].iloc[1]) and poses["time"].iloc[2] == 1.0


def test_duplicate_timestamps_are_accepted(tmp_path):
    """Frames are ordered by file name, never by time, so equal times change nothing."""
    path = write_poses(tmp_path, "name,x,y,time\nf0.png,0,0,5\nf1.png,1,0,5\nf2.png,2,0,5\n")
    poses = read_poses(path, NAMES)
    assert list(poses["name"]) == NAMES and list(poses["x"]) == [0.0, 1.0, 2.0]


def test_poses_for_a_file_not_in_the_folder_name_the_line(tmp_path):
    path = write_poses(tmp_path, "name,x,y\nf0.png,0,0\nf1.png,1,0\nf2.png,2,0\nf9.png,9,0\n")
    with pytest.raises(FrameReadError, match=r"line 5: frame 'f9\.png' is not an image"):
        read_poses(path, NAMES)


def test_poses_with_nan_reach_ground_truth_only_as_a_named_error():
    with pytest.raises(ValueError, match="query_xy contains NaN"):
        ground_truth_from_poses(np.zeros((3, 2)), np.array([[0.0, np.nan]]), max_distance=1.0)


# -------------------------------------------------- reference and query of different lengths

@pytest.mark.parametrize("n_reference, n_query", [(30, 18), (18, 30)])
def test_reference_and_query_of_different_lengths_are_matched_and_scored(n_reference, n_query):
    rng = np.random.default_rng(0)
    places = rng.normal(size=(max(n_reference, n_query), 16)).astype(np.float32)
    reference = places[:n_reference]
    query = places[:n_query] + 0.01 * rng.normal(size=(n_query, 16)).astype(np.float32)
    params = SeqSLAMParams.defaults(ds=4, r_window=4)
    result = match_sequences(reference, query, metric="sqeuclidean", params=params)
    truth = ground_truth_from_correspondence(n_reference, n_query)
    assert result.match.shape == (n_query,) and result.match.max() < n_reference
    assert (truth[n_reference:] == -1).all()
    metrics = loop_closure_metrics(result.match, result.confidence_score, truth, d_thresh=2)
    assert metrics["n_query"] == n_query
    assert metrics["n_positive"] == min(n_reference, n_query) - params.ds
    assert metrics["recall_at_1"] > 0.5


def test_poses_of_different_lengths_give_one_truth_per_query():
    reference = np.stack([np.arange(10.0), np.zeros(10)], axis=1)
    query = np.stack([np.arange(0.0, 20.0, 0.5), np.zeros(40)], axis=1)
    truth = ground_truth_from_poses(reference, query, max_distance=0.6)
    assert truth.shape == (40,)
    assert (truth[query[:, 0] > 9.6] == -1).all() and (truth[query[:, 0] <= 9.5] >= 0).all()
