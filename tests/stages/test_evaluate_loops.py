"""Stage ``evaluate_loops`` and its library (:mod:`cmal_lcd.evaluation.loop_route`).

A tiny dataset whose answer is known: one route, places 2 m apart; lap 1 (``r1/sunny``) covers
places 0..59, lap 2 under rain (``r1/rainy``) places 30..89 (half of it new), the same-weather
control's lap 2 (``r1/sunny_lap2``) places 0..59 again. Codes are one random vector per place
plus a per-weather offset, so a lap-2 frame on a place of lap 1 matches it.
"""

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from omegaconf import OmegaConf

from cmal_lcd.config import CONF_DIR
from cmal_lcd.evaluation.loop_route import evaluate_loop_route, loop_sequence, loops_of
from cmal_lcd.evaluation.protocol import MatchingProtocol
from cmal_lcd.matching import SeqSLAMParams
from cmal_lcd.matching.normalise import CodeNormalisation
from cmal_lcd.stages import evaluate_loops

DIM, SPACING, EXCLUDE = 12, 2.0, 10
DRIVES = {"r1/sunny": ("sunny", np.arange(0, 60)), "r1/rainy": ("rainy", np.arange(30, 90)),
          "r1/sunny_lap2": ("sunny", np.arange(0, 60))}
LOOPS = [["r1", "r1/sunny", "r1/rainy", "sunny-rainy"],
         ["r1", "r1/sunny", "r1/sunny_lap2", "sunny-sunny"]]


def loop_frames() -> pd.DataFrame:
    rows = [dict(split="test", route="r1", drive=drive, condition=condition,
                 x=float(p) * SPACING, y=0.3) for drive, (condition, places) in DRIVES.items()
            for p in places]
    frames = pd.DataFrame(rows)
    frames["heading"], frames["time"], frames["s"] = 0.0, np.nan, np.nan
    return frames


def loop_codes(frames: pd.DataFrame) -> np.ndarray:
    rng = np.random.default_rng(0)
    places = rng.normal(size=(100, DIM)) * 3.0
    offset = {"sunny": 0.0, "rainy": 0.5}
    codes = np.stack([places[int(round(x / SPACING))] + offset[c]
                      for x, c in zip(frames["x"], frames["condition"])])
    return (codes + 0.05 * rng.normal(size=codes.shape)).astype(np.float32)


def write_dataset(root: Path, *, loops=LOOPS) -> Path:
    train = pd.DataFrame([dict(split="train", route="", drive="", condition=c, x=np.nan, y=np.nan,
                               heading=np.nan, time=np.nan, s=np.nan)
                          for c in ("sunny", "rainy") for _ in range(4)])
    frames = pd.concat([train, loop_frames()], ignore_index=True)
    frames.insert(0, "frame", np.arange(len(frames)))
    frames = frames[["frame", "split", "route", "drive", "condition", "x", "y", "heading", "time",
                     "s"]]
    out = root / "dataset"
    out.mkdir(parents=True)
    np.save(out / "images.npy", np.zeros((len(frames), 8, 8, 3), np.uint8))
    frames.to_csv(out / "frames.csv", index=False)
    meta = {"kind": "test", "image_size": [8, 8], "conditions": ["sunny", "rainy"],
            "routes": ["r1"], "pairs": [["r1", "r1/sunny", "r1/rainy", "sunny-rainy"]],
            "validation_routes": [], "validation_pairs": [], "ground_truth": "poses",
            "config": {}}
    if loops:
        meta.update(loops=loops, loop_exclude_frames=EXCLUDE)
    (out / "dataset.json").write_text(json.dumps(meta))
    return out


def write_features(root: Path) -> Path:
    out = root / "features"
    out.mkdir()
    np.save(out / "codes.npy", loop_codes(loop_frames()))
    (out / "info.json").write_text(json.dumps({"method": "m", "label": "M", "metric":
                                               "sqeuclidean", "dim": DIM, "bytes_per_frame": 48}))
    return out


@pytest.fixture
def cfg():
    matching = OmegaConf.load(Path(CONF_DIR) / "matching" / "seqslam.yaml")
    matching.ds = 5
    matching.r_window = 4
    matching.d_thresh = 2
    matching.pose_tolerance = 1.5
    return OmegaConf.create({"matching": matching})


def write_protocol(root: Path, centre: str = "none") -> Path:
    path = root / "protocol.json"
    path.write_text(json.dumps({"selected": {"centre": centre, "l2": False, "enhance": True,
                                             "r_window": 4}}))
    return path


# ----------------------------------------------------------------------------- the library


def test_a_loop_is_lap_1_then_lap_2_in_time_order():
    frames = loop_frames()
    rows, n_lap1 = loop_sequence(frames, "r1/sunny", "r1/rainy")
    assert n_lap1 == 60 and len(rows) == 120
    assert (frames["drive"].to_numpy()[rows[:60]] == "r1/sunny").all()
    assert (frames["drive"].to_numpy()[rows[60:]] == "r1/rainy").all()
    np.testing.assert_array_equal(frames["x"].to_numpy()[rows] / SPACING,
                                  np.r_[np.arange(60), np.arange(30, 90)])
    with pytest.raises(ValueError, match="no frames"):
        loop_sequence(frames, "r1/sunny", "r1/foggy")
    with pytest.raises(ValueError, match="two drives"):
        loop_sequence(frames, "r1/sunny", "r1/sunny")


@pytest.mark.parametrize("lap2, revisited", [("r1/rainy", np.arange(30, 60)),
                                             ("r1/sunny_lap2", np.arange(0, 60))])
def test_lap_2_frames_on_lap_1_places_have_a_revisit_and_lap_1_frames_none(lap2, revisited):
    frames = loop_frames()
    evaluation = evaluate_loop_route(
        loop_codes(frames), frames, "r1/sunny", lap2, metric="sqeuclidean",
        params=SeqSLAMParams.defaults(ds=5, r_window=4), exclude_frames=EXCLUDE, pose_tolerance=1.5,
        d_thresh=2)
    truth = evaluation.truth
    assert (truth[:60] == -1).all()                      # lap 1: nothing older at its places
    places = DRIVES[lap2][1]
    has_revisit = truth[60:] >= 0
    np.testing.assert_array_equal(has_revisit, np.isin(places, revisited))
    np.testing.assert_array_equal(truth[60:][has_revisit], places[has_revisit])  # lap-1 frame
    m = evaluation.metrics
    assert m["n_lap1"] == 60 and m["n_lap2"] == 60 and m["n_revisit"] == len(revisited)
    assert m["recall_at_100p"] > 0.5 and m["auc_pr"] > 0.8


def test_the_protocol_centres_on_lap_1_as_the_reference_drive():
    frames = loop_frames()
    codes = loop_codes(frames) + 100.0      # a common offset: centring on lap 1 removes it
    options = dict(metric="sqeuclidean", params=SeqSLAMParams.defaults(ds=5, r_window=4),
                   exclude_frames=EXCLUDE, pose_tolerance=1.5, d_thresh=2)
    centred = evaluate_loop_route(
        codes, frames, "r1/sunny", "r1/rainy",
        protocol=MatchingProtocol(CodeNormalisation("reference"), enhance=True, r_window=4),
        **options)
    plain = evaluate_loop_route(loop_codes(frames), frames, "r1/sunny", "r1/rainy",
                                protocol=None, **options)
    assert centred.metrics["auc_pr"] == pytest.approx(plain.metrics["auc_pr"], abs=1e-6)


def test_loops_of_a_dataset_without_loops_is_empty():
    assert loops_of({"pairs": []}) == [] and loops_of({"loops": LOOPS}) == LOOPS


# ------------------------------------------------------------------------------- the stage


def test_the_stage_writes_every_loop_of_every_route(cfg, tmp_path):
    out = evaluate_loops.main(cfg, method="m", dataset_dir=write_dataset(tmp_path),
                              features_dir=write_features(tmp_path),
                              protocol_path=write_protocol(tmp_path), out_dir=tmp_path / "out")
    metrics = json.loads((out / "metrics.json").read_text())
    assert list(metrics) == ["r1"] and list(metrics["r1"]) == ["sunny-rainy", "sunny-sunny"]
    assert metrics["r1"]["sunny-sunny"]["lap2"] == "r1/sunny_lap2"
    assert metrics["r1"]["sunny-rainy"]["n_revisit"] == 30
    assert metrics["r1"]["sunny-sunny"]["n_revisit"] == 60
    table = pd.read_csv(out / "loops.csv")
    assert list(table.columns) == list(evaluate_loops.CSV_COLUMNS)
    assert table["loop"].tolist() == ["sunny-rainy", "sunny-sunny"]
    assert table["recall_at_100p"].tolist() == [metrics["r1"][n]["recall_at_100p"]
                                                for n in ("sunny-rainy", "sunny-sunny")]


def test_a_dataset_without_a_looping_route_says_so(cfg, tmp_path):
    out = evaluate_loops.main(cfg, method="m", dataset_dir=write_dataset(tmp_path, loops=None),
                              features_dir=write_features(tmp_path),
                              protocol_path=write_protocol(tmp_path), out_dir=tmp_path / "out")
    record = json.loads((out / "metrics.json").read_text())
    assert evaluate_loops.NO_LOOPS in record["skipped"]
    assert (out / "loops.csv").read_text().strip() == ",".join(evaluate_loops.CSV_COLUMNS)
