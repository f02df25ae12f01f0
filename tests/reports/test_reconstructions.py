"""Fig. 11's data: which held-out frames the report shows, beside which real view, and what the
trained CMAL makes of them (``cmal_lcd.reports.reconstructions``)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch

from cmal_lcd.data.store import FRAME_COLUMNS, load_dataset, save_dataset
from cmal_lcd.models import heldout_split
from cmal_lcd.models.cmal import reconstruct_and_translate
from cmal_lcd.models.images import resize_images
from cmal_lcd.reports import reconstructions as fig11

sys.path.insert(0, str(Path(__file__).parents[1] / "models"))
from model_helpers import write_model_file  # noqa: E402

torch.set_num_threads(1)

CONDITIONS = ["sunny", "foggy", "rainy"]
N_PLACES = 8
N_TEST = 3  # test frames come first: training row r is frame r + 3


def write_dataset(path: Path, conditions=CONDITIONS):
    """3 test frames, then 8 places (place k at x = 10 k) under each condition in turn
    (training row ``r``: place ``r % 8``, condition ``r // 8``)."""
    rng = np.random.default_rng(0)
    patterns = rng.integers(0, 200, (N_PLACES, 16, 16, 3))
    rows = [{"split": "test", "route": "route1", "drive": f"route1/{conditions[0]}",
             "condition": conditions[0], "x": float(i), "y": 0.0, "heading": 0.0,
             "time": float(i), "s": float(i)} for i in range(N_TEST)]
    images = [patterns[i] for i in range(N_TEST)]
    for k, condition in enumerate(conditions):
        for place in range(N_PLACES):
            rows.append({"split": "train", "route": "", "drive": "", "condition": condition,
                         "x": 10.0 * place, "y": 0.0, "heading": 0.0, "time": 0.0,
                         "s": np.nan})
            images.append(np.clip(patterns[place] + 25 * k, 0, 255))
    frames = pd.DataFrame(rows)
    frames.insert(0, "frame", np.arange(len(frames)))
    save_dataset(path, np.stack(images).astype(np.uint8), frames[list(FRAME_COLUMNS)],
                 {"kind": "test", "conditions": list(conditions), "routes": ["route1"],
                  "pairs": [], "image_size": [16, 16]})
    return load_dataset(path)


@pytest.fixture
def dataset(tmp_path):
    return write_dataset(tmp_path / "dataset")


# ----------------------------------------------------------------------- frame selection

def test_translation_pairs_are_reproducible_and_cover_ordered_pairs():
    labels = np.arange(30) % 3
    pos, a, b = fig11.translation_pairs(labels, n_conditions=3, count=6, seed=0)
    assert len(pos) == 6 and len(set(pos)) == 6
    assert np.all(labels[pos] == a) and np.all(a != b)
    assert set(zip(a, b)) == {(x, y) for x in range(3) for y in range(3) if x != y}
    again = fig11.translation_pairs(labels, n_conditions=3, count=6, seed=0)
    assert all(np.array_equal(u, v) for u, v in zip((pos, a, b), again))
    with pytest.raises(ValueError, match="n_conditions"):
        fig11.translation_pairs(labels, n_conditions=1, count=2, seed=0)


def test_translation_pairs_stop_when_every_frame_is_used():
    """One frame per condition: (0, 1) takes frame 0, (1, 0) frame 1, then nothing is left."""
    pos, a, b = fig11.translation_pairs(np.array([0, 1]), n_conditions=2, count=6, seed=0)
    assert pos.tolist() == [0, 1] and a.tolist() == [0, 1] and b.tolist() == [1, 0]


def test_nearest_view_prefers_a_frame_looking_the_same_way():
    candidates = np.array([[0.5, 0.0], [3.0, 0.0], [10.0, 0.0]])
    headings = np.array([np.pi, 0.1, 0.0])  # the nearest one looks the other way
    assert fig11.nearest_view(np.zeros(2), 0.0, candidates, headings) == 1
    assert fig11.nearest_view(np.zeros(2), np.pi / 2, candidates, headings) == 0  # none aligned
    with pytest.raises(ValueError, match="candidate_xy"):
        fig11.nearest_view(np.zeros(2), 0.0, np.zeros((0, 2)), np.zeros(0))


def test_frames_are_drawn_from_those_training_held_out():
    assert fig11.heldout_pool(24, heldout_fraction=0.25, seed=0).tolist() == \
        heldout_split(24, fraction=0.25, seed=0)[1].tolist()
    assert len(fig11.heldout_pool(24, heldout_fraction=0.25, seed=0)) == 6
    # nothing held out: every training frame is a candidate
    assert fig11.heldout_pool(5, heldout_fraction=0.0, seed=0).tolist() == [0, 1, 2, 3, 4]


def test_example_rows_are_held_out_rows_of_condition_a():
    labels = np.arange(24) % 3
    rows, a, b = fig11.example_rows(labels, n_conditions=3, heldout_fraction=0.25, seed=0,
                                    count=4)
    assert len(rows) == 4
    assert set(rows) <= set(heldout_split(24, fraction=0.25, seed=0)[1].tolist())
    assert np.array_equal(labels[rows], a) and np.all(a != b)


def test_the_real_view_is_the_same_place_under_condition_b():
    frames = pd.DataFrame({"x": [0.0, 10.0, 10.0, 0.0, 0.0], "y": 0.0, "heading": 0.0})
    labels = np.array([0, 0, 1, 1, 2])
    assert fig11.same_place_rows(frames, labels, np.array([0, 1, 1]),
                                 np.array([1, 1, 2])).tolist() == [3, 2, 4]


# ---------------------------------------------------------------------------- the arrays

def test_without_a_trained_cmal_model_there_is_nothing_and_the_reason_names_the_file(tmp_path,
                                                                                      dataset):
    models = tmp_path / "models"
    assert fig11.examples_missing(models, CONDITIONS) == (
        "`models/cmal/model.pt` does not exist (no trained CMAL model in this run).")
    assert fig11.reconstruction_examples(models, dataset, heldout_fraction=0.25, seed=0) is None


def test_with_one_condition_there_is_no_weather_to_translate_into(tmp_path):
    dataset = write_dataset(tmp_path / "dataset", conditions=["sunny"])
    write_model_file(tmp_path / "models", "cmal", conditions=["sunny", "foggy"])
    assert fig11.examples_missing(tmp_path / "models", ["sunny"]) == (
        "the dataset has 1 weather condition(s), so there is no other weather to translate into.")
    assert fig11.reconstruction_examples(tmp_path / "models", dataset, heldout_fraction=0.25,
                                         seed=0) is None
    assert fig11.examples_missing(tmp_path / "models", CONDITIONS) is None


@pytest.mark.parametrize("seed", [0, 1])
def test_each_held_out_frame_is_shown_with_its_reconstruction_translation_and_real_view(
        tmp_path, dataset, seed):
    model = write_model_file(tmp_path / "models", "cmal", conditions=CONDITIONS)
    got = fig11.reconstruction_examples(tmp_path / "models", dataset, heldout_fraction=0.25,
                                        seed=seed)
    assert list(got) == list(fig11.EXAMPLE_KEYS)
    frames, images = dataset.frames, np.asarray(dataset.images)
    fa, fb = got["frame_a"], got["frame_b"]
    # 24 training frames, a quarter held out: those 6 frames, each once
    heldout = heldout_split(24, fraction=0.25, seed=seed)[1]
    assert sorted(fa.tolist()) == (heldout + N_TEST).tolist()
    assert (frames["split"].to_numpy()[fb] == "train").all()
    # A under its own condition, B another one; b is A's place (same x) under B
    np.testing.assert_array_equal(frames["condition"].to_numpy()[fa], got["condition_a"])
    np.testing.assert_array_equal(frames["condition"].to_numpy()[fb], got["condition_b"])
    assert (got["condition_a"] != got["condition_b"]).all()
    np.testing.assert_array_equal(frames["x"].to_numpy()[fb], frames["x"].to_numpy()[fa])
    # the model is at the frames' size (16): a and b are the frames themselves
    np.testing.assert_array_equal(got["a"], images[fa])
    np.testing.assert_array_equal(got["b"], images[fb])
    index = {name: i for i, name in enumerate(CONDITIONS)}
    expected = reconstruct_and_translate(model, images[fa],
                                         [index[c] for c in got["condition_a"]],
                                         [index[c] for c in got["condition_b"]])
    for key in ("recon_a", "translated_b"):
        np.testing.assert_array_equal(got[key], expected[key])
        assert got[key].shape == (6, 16, 16, 3) and got[key].dtype == np.uint8


def test_frames_are_shown_at_the_models_image_size(tmp_path, dataset):
    write_model_file(tmp_path / "models", "cmal", conditions=CONDITIONS, image_size=8)
    got = fig11.reconstruction_examples(tmp_path / "models", dataset, heldout_fraction=0.25,
                                        seed=0, count=2)
    images = np.asarray(dataset.images)
    assert len(got["frame_a"]) == 2
    for key in ("a", "recon_a", "translated_b", "b"):
        assert got[key].shape == (2, 8, 8, 3)
    np.testing.assert_array_equal(got["b"], resize_images(images[got["frame_b"]], image_size=8))


def test_the_same_model_and_seed_give_the_same_arrays(tmp_path, dataset):
    write_model_file(tmp_path / "models", "cmal", conditions=CONDITIONS)
    first, second = (fig11.reconstruction_examples(tmp_path / "models", dataset,
                                                   heldout_fraction=0.25, seed=0)
                     for _ in range(2))
    assert all(np.array_equal(first[k], second[k]) for k in fig11.EXAMPLE_KEYS)


def test_each_real_view_says_how_far_it_is_from_a(tmp_path, dataset):
    """Issue 37: Fig. 11's B column was not visibly A's place; each B now carries its distance
    and turn from A (here every B is at A's x, heading 0)."""
    write_model_file(tmp_path / "models", "cmal", conditions=CONDITIONS)
    got = fig11.reconstruction_examples(tmp_path / "models", dataset, heldout_fraction=0.25,
                                        seed=0)
    assert got["offset_b"].tolist() == ["0.0 m, 0° away"] * len(got["frame_a"])


def test_view_offsets_in_metres_and_degrees_or_in_places():
    frames = pd.DataFrame({"x": [0.0, 3.0, 7.0], "y": [0.0, 4.0, 0.0],
                           "heading": [np.radians(175.0), np.radians(-170.0), 0.0]})
    rows_a, rows_b = np.array([0, 0, 2]), np.array([1, 2, 1])
    assert fig11.view_offsets(frames, rows_a, rows_b, metres=True).tolist() == [
        "5.0 m, 15° away", "7.0 m, 175° away", "5.7 m, 170° away"]
    assert fig11.view_offsets(frames, rows_a, rows_b, metres=False).tolist() == [
        "5 places away", "7 places away", "6 places away"]
    assert fig11.view_offsets(frames, np.array([0, 0]), np.array([0, 1]),
                              metres=False).tolist() == ["same place index", "5 places away"]
