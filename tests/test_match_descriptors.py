"""``cmal-lcd match`` on descriptor files and with ``--ground-truth`` files of the field."""

import json

import cv2

import numpy as np
import pytest

from cmal_lcd.commands import main
from mat_files import save_mat_v5, save_mat_v73

N_REF, N_QUERY, DIMS = 70, 60, 24
#: Query frame q shows reference place q + OFFSET (the query drive starts later).
OFFSET = 5


def route_descriptors(seed: int = 0):
    """``(reference (R, D), query (Q, D))``: a smooth random route and a noisy later drive."""
    rng = np.random.default_rng(seed)
    places = np.cumsum(rng.normal(size=(N_REF, DIMS)), axis=0)
    reference = places + 0.3 * rng.normal(size=places.shape)
    query = places[OFFSET:OFFSET + N_QUERY] + 3.0 * rng.normal(size=(N_QUERY, DIMS))
    return reference.astype(np.float32), query.astype(np.float32)


def gt_matrices(hard_radius: int, soft_radius: int):
    """VPR_Tutorial-style ``GThard``/``GTsoft`` (reference x query) around the true place."""
    r = np.arange(N_REF)[:, None]
    place = np.arange(N_QUERY)[None, :] + OFFSET
    return np.abs(r - place) <= hard_radius, np.abs(r - place) <= soft_radius


def nearest_rows(reference, query) -> np.ndarray:
    """Independent single-frame nearest neighbour: ``int (Q,)`` argmin of squared distance."""
    d = ((reference[:, None, :].astype(np.float64) - query[None, :, :]) ** 2).sum(axis=2)
    return d.argmin(axis=0)


def run_match(tmp_path, *args):
    out = tmp_path / "out"
    code = main(["match", *map(str, args), "--out", str(out), "--no-figures"])
    return code, out


@pytest.mark.parametrize("save", [save_mat_v5, save_mat_v73], ids=["v5", "v7.3"])
def test_matlab_descriptors_and_gt_struct(tmp_path, save, capsys):
    reference, query = route_descriptors()
    hard, soft = gt_matrices(hard_radius=1, soft_radius=4)
    save(tmp_path / "day_right.mat", {"Y": reference})
    save(tmp_path / "night_right.mat", {"Y": query})
    save(tmp_path / "gt.mat", {"GT": {"GThard": hard, "GTsoft": soft}})
    code, out = run_match(tmp_path, tmp_path / "day_right.mat", tmp_path / "night_right.mat",
                          "--ground-truth", tmp_path / "gt.mat")
    assert code == 0, capsys.readouterr().err
    metrics = json.loads((out / "metrics.json").read_text())
    assert (metrics["n_reference"], metrics["n_query"]) == (N_REF, N_QUERY)
    assert metrics["params"]["features"] == "precomputed"
    assert metrics["ground_truth"]["kind"] == "file"
    assert "GTsoft-only entries ignored" in metrics["ground_truth"]["tolerance"]
    # single-frame recall@1, computed here independently: a nearest row that is GTsoft-only
    # is neither right nor wrong (left out); the rest are right when GThard holds them
    nn = nearest_rows(reference, query)
    columns = np.arange(N_QUERY)
    ignored = soft[nn, columns] & ~hard[nn, columns]
    assert ignored.any() and not ignored.all()  # the left-out path is exercised
    expected = hard[nn, columns][~ignored].sum() / (~ignored).sum()
    assert metrics["single_frame"]["recall_at_1"] == pytest.approx(expected)
    assert metrics["single_frame"]["n_scored"] == int((~ignored).sum())
    assert "single frame" in capsys.readouterr().out


def test_recall_at_1_equals_vpr_tutorial_without_gtsoft(tmp_path):
    """With GThard alone, single-frame recall@1 is VPR_Tutorial's ``recallAtK(S, GT, K=1)``
    (``evaluation/metrics.py``: queries without a true reference dropped; here every query
    has one), re-implemented from its definition with S = -D."""
    reference, query = route_descriptors(seed=3)
    hard, _ = gt_matrices(hard_radius=2, soft_radius=2)
    np.save(tmp_path / "ref.npy", reference)
    np.savez(tmp_path / "query.npz", descriptors=query)
    np.savez(tmp_path / "gt.npz", GThard=hard)
    code, out = run_match(tmp_path, tmp_path / "ref.npy", tmp_path / "query.npz",
                          "--ground-truth", tmp_path / "gt.npz")
    assert code == 0
    metrics = json.loads((out / "metrics.json").read_text())
    S = -((reference[:, None, :].astype(np.float64) - query[None, :, :]) ** 2).sum(axis=2)
    best = S.argsort(axis=0)[-1:, :]  # the K = 1 most similar rows per column
    vpr_tutorial_r1 = np.sum(hard[best, np.arange(N_QUERY)].sum(axis=0) > 0) / N_QUERY
    assert metrics["single_frame"]["recall_at_1"] == pytest.approx(vpr_tutorial_r1)
    assert 0 < vpr_tutorial_r1 < 1  # a test that could fail either way


def test_descriptors_without_ground_truth_match_by_row(tmp_path):
    reference, _ = route_descriptors()
    np.save(tmp_path / "a.npy", reference)
    np.save(tmp_path / "b.npy", reference + 0.01)
    code, out = run_match(tmp_path, tmp_path / "a.npy", tmp_path / "b.npy")
    assert code == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["ground_truth"]["kind"] == "index"
    assert metrics["ground_truth"]["frame_order"] == "rows of the descriptor files"
    assert metrics["recall_at_1"] == 1.0


def test_corridor_folders_with_vpr_bench_ground_truth(tmp_path, corridor_dir):
    code, out = run_match(tmp_path, corridor_dir / "ref", corridor_dir / "query",
                          "--ground-truth", corridor_dir / "ground_truth_new.npy")
    assert code == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert (metrics["n_reference"], metrics["n_query"]) == (111, 111)
    assert metrics["single_frame"]["n_query"] == 111
    assert metrics["ground_truth"]["source"].startswith("VPR-Bench ground_truth_new.npy")
    assert metrics["ground_truth"]["n_query_without_reference"] == 0
    for block in (metrics, metrics["single_frame"]):
        assert 0 <= block["recall_at_1"] <= block["recall_at_5"] <= block["recall_at_20"] <= 1


def _write_bad_inputs(tmp_path, case):
    reference, query = route_descriptors()
    np.save(tmp_path / "ref.npy", reference)
    np.save(tmp_path / "query.npy", query)
    hard, _ = gt_matrices(1, 1)
    np.savez(tmp_path / "gt.npz", GThard=hard)
    (tmp_path / "frames").mkdir()
    args = {
        "mixed": ["ref.npy", "frames"],
        "features": ["ref.npy", "query.npy", "--features", "dnn"],
        "key_with_folders": ["frames", "frames", "--descriptor-key", "x"],
        "wrong_key": ["ref.npy", "query.npy", "--descriptor-key", "x"],
        "dims": ["ref.npy", "short.npy"],
        "nan": ["ref.npy", "nan.npy"],
        "gt_rows": ["ref.npy", "fewer.npy", "--ground-truth", "gt.npz"],
        "gt_missing": ["ref.npy", "query.npy", "--ground-truth", "none.npy"],
    }[case]
    np.save(tmp_path / "short.npy", query[:, :10])
    bad = query.copy()
    bad[7, 3] = np.nan
    np.save(tmp_path / "nan.npy", bad)
    np.save(tmp_path / "fewer.npy", query[:50])
    return [str(tmp_path / a) if not a.startswith("--") and a not in ("dnn", "x") else a
            for a in args]


@pytest.mark.parametrize("case, named", [
    ("mixed", "frames: a folder of frames, but"),
    ("features", "--features dnn: descriptor files are matched as given"),
    ("key_with_folders", "--descriptor-key x: only with descriptor files"),
    ("wrong_key", "ref.npy: no array named 'x'"),
    ("dims", "short.npy: descriptors of 10 dimensions, but"),
    ("nan", "nan.npy: row 7 holds NaN or infinite values"),
    ("gt_rows", "gt.npz: GThard is 70 x 60 (reference x query), but there are 70 reference "
                "and 50 query frames"),
    ("gt_missing", "none.npy: no such file"),
])
def test_bad_descriptor_and_ground_truth_inputs(tmp_path, capsys, case, named):
    args = _write_bad_inputs(tmp_path, case)
    out = tmp_path / "out"
    assert main(["match", *args, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert named in err and len(err.splitlines()) == 1, err
    assert not out.exists()


def downloader_name(east: float, north: float, timestamp: str) -> str:
    """A VPR-datasets-downloader file name (its ``util.py``: ``get_dst_image_name``)."""
    return (f"@{east:010.2f}@{north:010.2f}@10@S@037.75319@-122.40861@pano@@@@@@{timestamp}"
            f"@@.jpg")


def write_utm_drive(folder, easts, *, seed):
    """Frames along a road heading north-east, named by position and time; the time order is
    not the name order (east decreases along the drive)."""
    rng = np.random.default_rng(seed)
    texture = rng.random((24, 32 + 4 * len(easts)))
    folder.mkdir()
    for i, east in enumerate(easts):
        crop = (255 * texture[:, 4 * i:4 * i + 32]).astype(np.uint8)
        name = downloader_name(500000.0 + east, 4100000.0 + 2 * i, f"20190101_10{i:02d}00")
        assert cv2.imwrite(str(folder / name), crop)


def test_utm_ground_truth_from_downloader_names(tmp_path):
    easts = 3.0 * np.arange(40)[::-1]  # travel order: east decreasing
    write_utm_drive(tmp_path / "database", easts, seed=0)
    write_utm_drive(tmp_path / "queries", easts + 1.0, seed=0)
    code, out = run_match(tmp_path, tmp_path / "database", tmp_path / "queries",
                          "--ground-truth", "utm", "--positive-dist-threshold", "5")
    assert code == 0
    metrics = json.loads((out / "metrics.json").read_text())
    truth = metrics["ground_truth"]
    assert truth["frame_order"] == "VPR-datasets-downloader names, by their timestamp field"
    assert truth["tolerance"].startswith("5 m (UTM east/north")
    # independent count: pairs within 5 m, frames in time order (i = row in both folders)
    xy = np.column_stack([easts, 2.0 * np.arange(40)])
    distance = np.linalg.norm(xy[:, None, :] - (xy + [1.0, 0.0])[None, :, :], axis=2)
    assert truth["n_right_pairs"] == int(np.sum(distance <= 5))
    assert metrics["recall_at_1"] == 1.0  # the same texture at the same time index


@pytest.mark.parametrize("radius, message", [("-1", "must be > 0.0, got -1.0"),
                                             ("nan", "must be a finite number, got nan")])
def test_a_bad_radius_is_refused_by_the_schemas_rule_naming_the_option(tmp_path, capsys,
                                                                        radius, message):
    easts = 3.0 * np.arange(12)[::-1]
    write_utm_drive(tmp_path / "database", easts, seed=0)
    write_utm_drive(tmp_path / "queries", easts + 1.0, seed=0)
    code, out = run_match(tmp_path, tmp_path / "database", tmp_path / "queries",
                          "--ground-truth", "utm", "--positive-dist-threshold", radius)
    assert code == 2 and not out.exists()
    assert f"--positive-dist-threshold: {message}" in capsys.readouterr().err


def test_the_default_radius_is_the_one_in_conf(tmp_path, monkeypatch):
    """No second copy in Python: another conf/data/folders.yaml gives another radius."""
    import shutil

    from cmal_lcd import checkout

    conf = tmp_path / "conf"
    shutil.copytree(checkout.CONF_DIR, conf)
    folders = conf / "data" / "folders.yaml"
    text = folders.read_text()
    assert "\npositive_dist_threshold: 25.0 " in text
    folders.write_text(text.replace("\npositive_dist_threshold: 25.0 ",
                                    "\npositive_dist_threshold: 4.0 "))
    monkeypatch.setattr(checkout, "CONF_DIR", conf)
    easts = 3.0 * np.arange(40)[::-1]
    write_utm_drive(tmp_path / "database", easts, seed=0)
    write_utm_drive(tmp_path / "queries", easts + 1.0, seed=0)
    code, out = run_match(tmp_path, tmp_path / "database", tmp_path / "queries",
                          "--ground-truth", "utm")
    assert code == 0
    truth = json.loads((out / "metrics.json").read_text())["ground_truth"]
    assert truth["tolerance"].startswith("4 m (UTM east/north")


def test_utm_refuses_names_without_coordinates(tmp_path, capsys):
    from test_cli import write_route

    reference = write_route(tmp_path / "a", brightness=1.0, seed=1)
    query = write_route(tmp_path / "b", brightness=0.8, seed=2)
    code, out = run_match(tmp_path, reference, query, "--ground-truth", "utm")
    assert code == 2 and not out.exists()
    assert "frame-0000.png: no UTM coordinates in the file name" in capsys.readouterr().err


def test_exports_agree_with_the_metrics(tmp_path):
    """matches.csv, candidates.npz, descriptors.npz and difference_matrix.npz say what the
    metrics were computed from."""
    import csv

    reference, query = route_descriptors(seed=5)
    hard, soft = gt_matrices(hard_radius=1, soft_radius=3)
    np.save(tmp_path / "ref.npy", reference)
    np.save(tmp_path / "query.npy", query)
    np.savez(tmp_path / "gt.npz", GThard=hard, GTsoft=soft)
    code, out = run_match(tmp_path, tmp_path / "ref.npy", tmp_path / "query.npy",
                          "--ground-truth", tmp_path / "gt.npz", "--save-descriptors",
                          "--save-matrix")
    assert code == 0
    metrics = json.loads((out / "metrics.json").read_text())
    with open(out / "matches.csv", newline="") as handle:
        rows = list(csv.DictReader(handle))
    assert len(rows) == N_QUERY
    verdicts = [row["verdict"] for row in rows]
    assert verdicts.count("right") + verdicts.count("wrong") == metrics["n_scored"]
    assert verdicts.count("right") == round(metrics["recall_at_1"] * metrics["n_scored"])
    single = [row["single_frame_verdict"] for row in rows]
    assert single.count("right") == round(metrics["single_frame"]["recall_at_1"]
                                          * metrics["single_frame"]["n_scored"])
    candidates = np.load(out / "candidates.npz")
    scored = candidates["match"] >= 0
    assert np.array_equal(candidates["sequence_top_k"][scored, 0], candidates["match"][scored])
    assert np.array_equal(candidates["single_frame_match"], nearest_rows(reference, query))
    assert [int(row["match"]) for row in rows] == candidates["match"].tolist()
    np.testing.assert_allclose(candidates["sequence_top_k_score"][scored, 0],
                               candidates["score"][scored])
    sf_rows = candidates["single_frame_top_k"]
    np.testing.assert_allclose(candidates["single_frame_top_k_difference"],
                               np.load(out / "difference_matrix.npz")["D"][
                                   sf_rows, np.arange(N_QUERY)[:, None]], rtol=1e-6)
    saved = np.load(out / "descriptors.npz")
    assert np.array_equal(saved["reference"], reference) and np.array_equal(saved["query"], query)
    matrix = np.load(out / "difference_matrix.npz")
    assert matrix["D"].shape == (N_REF, N_QUERY)
    assert np.array_equal(matrix["D"].argmin(axis=0), candidates["single_frame_match"])
