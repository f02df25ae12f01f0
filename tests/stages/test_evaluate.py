"""Stage ``evaluate``: which drive is the reference, which pair is which, which tolerance.

A tiny dataset whose answer is known without running SeqSLAM: one route, places 2 m apart;
drive ``sunny`` covers places 0..59, drive ``foggy`` places 30..69 (offset, different length).
Codes are one random vector per place, so each query's best match is known; the codes of the
``foggy`` frames are those of the place ``SHIFT`` further on, so every correct sequence match
is exactly ``SHIFT`` frames from the true place (tests ``d_thresh`` at its boundary).

Pairs: ``sunny-foggy`` (reference sunny, query foggy) and ``foggy-sunny`` (the reverse); the
two have different query lengths and different true places, so swapping reference and query,
or writing one pair's results under the other's name, changes the files.
"""

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from omegaconf import OmegaConf

from cmal_lcd.config import CONF_DIR
from cmal_lcd.stages import evaluate

DIM, SPACING, SHIFT = 12, 2.0, 2
SUNNY, FOGGY = np.arange(0, 60), np.arange(30, 70)   # places of each drive's frames


def write_dataset(root: Path) -> Path:
    rows = [dict(split="train", route="", drive="", condition=c, x=np.nan, y=np.nan)
            for c in ("sunny", "foggy") for _ in range(4)]
    for condition, places in (("sunny", SUNNY), ("foggy", FOGGY)):
        rows += [dict(split="test", route="r1", drive=f"r1/{condition}", condition=condition,
                      x=float(p) * SPACING, y=0.3) for p in places]
    frames = pd.DataFrame(rows)
    frames.insert(0, "frame", np.arange(len(frames)))
    frames["heading"], frames["time"], frames["s"] = 0.0, np.nan, np.nan
    out = root / "dataset"
    out.mkdir(parents=True)
    np.save(out / "images.npy", np.zeros((len(frames), 8, 8, 3), np.uint8))
    frames.to_csv(out / "frames.csv", index=False)
    meta = {"kind": "test", "image_size": [8, 8], "conditions": ["sunny", "foggy"],
            "routes": ["r1"],
            "pairs": [["r1", "r1/sunny", "r1/foggy", "sunny-foggy"],
                      ["r1", "r1/foggy", "r1/sunny", "foggy-sunny"]],
            "validation_routes": [], "validation_pairs": [], "ground_truth": "poses",
            "config": {}}
    (out / "dataset.json").write_text(json.dumps(meta))
    return out


def write_features(root: Path) -> Path:
    rng = np.random.default_rng(0)
    places = rng.normal(size=(80, DIM)) * 3.0
    codes = np.concatenate([places[SUNNY], places[FOGGY + SHIFT]])
    codes = codes + 0.05 * rng.normal(size=codes.shape)
    out = root / "features"
    out.mkdir()
    np.save(out / "codes.npy", codes.astype(np.float32))
    np.save(out / "train_codes.npy", rng.normal(size=(8, DIM)).astype(np.float32))
    np.save(out / "train_labels.npy", np.repeat([0, 1], 4).astype(np.int64))
    (out / "info.json").write_text(json.dumps({"method": "m", "label": "M", "metric":
                                               "sqeuclidean", "dim": DIM, "bytes_per_frame": 48}))
    return out


def expected_truth(reference: np.ndarray, query: np.ndarray) -> np.ndarray:
    """Index into ``reference`` of each query's place; -1 when absent (2 m > 1.5 m tolerance)."""
    where = {int(p): i for i, p in enumerate(reference)}
    return np.array([where.get(int(p), -1) for p in query], np.int64)


@pytest.fixture
def cfg():
    matching = OmegaConf.load(Path(CONF_DIR) / "matching" / "seqslam.yaml")
    matching.ds = 5
    matching.r_window = 4
    matching.d_thresh = SHIFT
    matching.pose_tolerance = 1.5
    return OmegaConf.create({"matching": matching})


def run(cfg, tmp_path) -> Path:
    protocol = tmp_path / "protocol.json"
    protocol.write_text(json.dumps({"selected": {"centre": "none", "l2": False,
                                                 "enhance": False, "r_window": 4}}))
    return evaluate.main(cfg, method="m", dataset_dir=write_dataset(tmp_path),
                         features_dir=write_features(tmp_path), protocol_path=protocol,
                         out_dir=tmp_path / "evaluation")


def test_each_pair_matches_its_query_drive_against_its_reference_drive(cfg, tmp_path):
    out = run(cfg, tmp_path)
    for pair, reference, query in (("sunny-foggy", SUNNY, FOGGY), ("foggy-sunny", FOGGY, SUNNY)):
        saved = np.load(out / "matrices" / "r1" / f"{pair}.npz")
        assert saved["D"].shape == (len(reference), len(query)), pair
        np.testing.assert_array_equal(saved["truth"], expected_truth(reference, query))
        scored = saved["match"] >= 0
        assert scored.sum() >= len(query) // 2, pair


def test_matches_land_shift_frames_from_the_true_place(cfg, tmp_path):
    """Sanity of the construction: the codes of a foggy frame look like the place SHIFT on."""
    out = run(cfg, tmp_path)
    saved = np.load(out / "matrices" / "r1" / "sunny-foggy.npz")
    ok = (saved["match"] >= 0) & (saved["truth"] >= 0) & (saved["truth"] + SHIFT < len(SUNNY))
    assert ok.sum() > 10
    np.testing.assert_array_equal(saved["match"][ok] - saved["truth"][ok], SHIFT)


def correct_count(out: Path, pair: str, d_thresh: int) -> tuple[int, int, int]:
    """From the saved matches: (#correct within d_thresh, #exactly SHIFT away, #scored)."""
    saved = np.load(out / "matrices" / "r1" / f"{pair}.npz")
    m, t = saved["match"], saved["truth"]
    ok = (m >= 0) & (t >= 0)
    return (int(np.sum(ok & (np.abs(m - t) <= d_thresh))), int(np.sum(ok & (m - t == SHIFT))),
            int(np.sum(m >= 0)))


def test_a_match_exactly_d_thresh_frames_away_is_correct(cfg, tmp_path):
    out = run(cfg, tmp_path)
    metrics = json.loads((out / "metrics.json").read_text())
    assert set(metrics) == {"r1"} and set(metrics["r1"]) == {"sunny-foggy", "foggy-sunny"}
    assert set(metrics["r1"]["sunny-foggy"]) == {"selected", "paper"}
    correct, at_shift, scored = correct_count(out, "sunny-foggy", SHIFT)
    assert at_shift >= 20 and correct >= at_shift
    assert metrics["r1"]["sunny-foggy"]["selected"]["recall_at_1"] == pytest.approx(
        correct / scored)
    assert metrics["r1"]["sunny-foggy"]["selected"]["n_query"] == len(FOGGY)


def test_a_tighter_d_thresh_makes_the_same_matches_wrong(cfg, tmp_path):
    cfg.matching.d_thresh = SHIFT - 1
    out = run(cfg, tmp_path)
    metrics = json.loads((out / "metrics.json").read_text())
    correct, at_shift, scored = correct_count(out, "sunny-foggy", SHIFT - 1)
    assert at_shift >= 20 and correct <= 2
    assert metrics["r1"]["sunny-foggy"]["selected"]["recall_at_1"] == pytest.approx(
        correct / scored)


def test_the_strict_variant_scores_the_same_matches_as_a_run_at_that_tolerance(cfg, tmp_path):
    for sub in ("a", "b"):
        (tmp_path / sub).mkdir()
    cfg.matching.d_thresh_strict = SHIFT - 1
    both = json.loads((run(cfg, tmp_path / "a") / "metrics.json").read_text())
    cfg.matching.d_thresh, cfg.matching.d_thresh_strict = SHIFT - 1, None
    tight = json.loads((run(cfg, tmp_path / "b") / "metrics.json").read_text())
    for pair in ("sunny-foggy", "foggy-sunny"):
        strict = both["r1"][pair]["strict"]
        assert strict.pop("d_thresh") == SHIFT - 1
        assert strict == tight["r1"][pair]["selected"], pair
        assert "strict" not in tight["r1"][pair]
    assert both["r1"]["sunny-foggy"]["selected"]["recall_at_1"] > 0.5 > strict["recall_at_1"]


def test_a_strict_tolerance_looser_than_d_thresh_is_refused_at_composition():
    from cmal_lcd.config import compose
    from cmal_lcd.schema import SchemaError

    with pytest.raises(SchemaError, match="matching.d_thresh_strict"):
        compose(["matching.d_thresh=2", "matching.d_thresh_strict=3"])


def test_pose_tolerance_decides_which_queries_have_a_true_place(cfg, tmp_path):
    """With 5 m, the query 2 m beyond the reference's end has a true place (the last frame)."""
    cfg.matching.pose_tolerance = 5.0
    out = run(cfg, tmp_path)
    truth = np.load(out / "matrices" / "r1" / "sunny-foggy.npz")["truth"]
    expected = expected_truth(SUNNY, FOGGY)
    assert expected[FOGGY == 60] == -1 and truth[FOGGY == 60] == len(SUNNY) - 1
    np.testing.assert_array_equal(truth[FOGGY > 62], -1)


def test_pr_curve_of_every_pair_is_written_and_ends_at_its_recall(cfg, tmp_path):
    out = run(cfg, tmp_path)
    metrics = json.loads((out / "metrics.json").read_text())
    for pair in ("sunny-foggy", "foggy-sunny"):
        table = pd.read_csv(out / "pr" / "r1" / f"{pair}.csv")
        assert list(table.columns) == ["recall", "precision", "threshold"]
        assert len(table) > 0 and np.isfinite(table.to_numpy()).all()
        assert 0 < metrics["r1"][pair]["selected"]["auc_pr"] <= 1


def test_the_two_directions_of_a_pair_are_different_results(cfg, tmp_path):
    """Sunny has 60 frames, foggy 40: a stage that swapped reference and query, or wrote one
    pair's results under the other's name, would give each pair the other's counts."""
    out = run(cfg, tmp_path)
    a = np.load(out / "matrices" / "r1" / "sunny-foggy.npz")
    b = np.load(out / "matrices" / "r1" / "foggy-sunny.npz")
    assert len(a["match"]) == len(FOGGY) and len(b["match"]) == len(SUNNY)
    assert (a["truth"] >= 0).sum() == (b["truth"] >= 0).sum() == 30


def test_exports_of_each_pair_agree_with_its_metrics(cfg, tmp_path):
    out = run(cfg, tmp_path)
    metrics = json.loads((out / "metrics.json").read_text())
    for pair, query in (("sunny-foggy", FOGGY), ("foggy-sunny", SUNNY)):
        table = pd.read_csv(out / "matches" / "r1" / f"{pair}.csv", keep_default_na=False)
        selected = metrics["r1"][pair]["selected"]
        assert len(table) == len(query)
        verdicts = table["verdict"].tolist()
        assert verdicts.count("right") == round(selected["recall_at_1"] * selected["n_scored"])
        assert verdicts.count("right") + verdicts.count("wrong") == selected["n_scored"]
        candidates = np.load(out / "candidates" / "r1" / f"{pair}.npz")
        scored = candidates["match"] >= 0
        assert np.array_equal(candidates["sequence_top_k"][scored, 0],
                              candidates["match"][scored])
        assert table["query_frame"].astype(str).tolist() == candidates["query_frames"].tolist()


def test_a_stored_ground_truth_file_replaces_d_thresh(cfg, tmp_path):
    """dataset.json's ground_truth_sets (a file's, cut by the dataset stage): only the listed
    row is right, so matches SHIFT frames away are wrong although d_thresh = SHIFT."""
    dataset = write_dataset(tmp_path)
    meta = json.loads((dataset / "dataset.json").read_text())
    meta["ground_truth"] = "file"
    meta["ground_truth_source"] = {"source": "test file", "tolerance": "as listed"}
    meta["ground_truth_sets"] = []
    for _, reference, query, name in meta["pairs"]:
        ref_places, query_places = (SUNNY, FOGGY) if name == "sunny-foggy" else (FOGGY, SUNNY)
        truth = expected_truth(ref_places, query_places)
        right = [[int(r), q] for q, r in enumerate(truth) if r >= 0]
        meta["ground_truth_sets"].append({"reference": reference, "query": query,
                                          "right": right, "ignored": [],
                                          "shape": [len(ref_places), len(query_places)]})
    (dataset / "dataset.json").write_text(json.dumps(meta))
    protocol = tmp_path / "protocol.json"
    protocol.write_text(json.dumps({"selected": {"centre": "none", "l2": False,
                                                 "enhance": False, "r_window": 4}}))
    out = evaluate.main(cfg, method="m", dataset_dir=dataset,
                        features_dir=write_features(tmp_path), protocol_path=protocol,
                        out_dir=tmp_path / "evaluation")
    metrics = json.loads((out / "metrics.json").read_text())
    saved = np.load(out / "matrices" / "r1" / "sunny-foggy.npz")
    m, t = saved["match"], expected_truth(SUNNY, FOGGY)
    scored = m >= 0
    exact = int(np.sum(scored & (t >= 0) & (m == t)))
    assert metrics["r1"]["sunny-foggy"]["selected"]["recall_at_1"] == pytest.approx(
        exact / scored.sum())
    assert exact <= 2  # the matches land SHIFT frames on: wrong under the file
    assert saved["truth"].dtype == np.int64  # never a pickled object
