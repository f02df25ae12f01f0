"""``data.kind: folders`` with a ground-truth file or UTM names (``data.ground_truth``)."""

from __future__ import annotations

import numpy as np
import pytest

from cmal_lcd.data.folders import FolderDatasetError, build_folder_dataset
from cmal_lcd.data.store import load_dataset, save_dataset
from cmal_lcd.data.ground_truth import ReferenceSets
from cmal_lcd.evaluation.loop_closure import (dataset_ground_truth, drive_rows,
                                              evaluate_drive_pairs, ground_truth_for_pair)
from cmal_lcd.matching import SeqSLAMParams
from test_folders import config, write_frames

N = 30  # frames per season folder: train 1-10, validation 11-18, test 19-30


@pytest.fixture
def seasons(tmp_path):
    write_frames(tmp_path / "summer", N, seed=1)
    write_frames(tmp_path / "winter", N, seed=2)
    return tmp_path


def vpr_bench_file(path, lists):
    rows = np.empty((len(lists), 2), dtype=object)
    for q, references in enumerate(lists):
        rows[q, 0], rows[q, 1] = q, list(references)
    np.save(path, rows, allow_pickle=True)
    return path


def file_config(root, gt_path, **changes):
    return config(root, **{"ground_truth": "file", "ground_truth_file": str(gt_path),
                           "train.range": [1, 10], "test.range": [19, None],
                           "validation": {"range": [11, 18]}, **changes})


def test_file_ground_truth_is_cut_to_each_split_and_renumbered(seasons, tmp_path):
    # the query drive lags by 2: query q shows reference q - 2 (+-1); queries 0, 1 have none
    lists = [[] if q < 2 else range(max(0, q - 3), min(N, q)) for q in range(N)]
    gt = vpr_bench_file(tmp_path / "gt.npy", lists)
    _, frames, meta = build_folder_dataset(file_config(seasons, gt), seed=0)
    assert meta["ground_truth"] == "file"
    assert meta["ground_truth_source"]["source"].startswith("VPR-Bench ground_truth_new.npy")
    assert len(meta["ground_truth_source"]["sha256"]) == 64
    truth = dataset_ground_truth(meta)
    assert set(truth) == {("line/summer", "line/winter"),
                          ("line_val/summer", "line_val/winter")}
    test = truth[("line/summer", "line/winter")]
    assert (test.n_reference, test.n_query) == (12, 12)
    # test query j is folder query 18 + j; its right rows are folder rows 15 + j .. 17 + j,
    # of which those >= 18 are in the test reference (test row = folder row - 18)
    for j in range(12):
        expected = [r - 18 for r in range(15 + j, 18 + j) if r >= 18]
        assert test.right_rows(j).tolist() == expected
    val = truth[("line_val/summer", "line_val/winter")]
    assert val.right_rows(0).tolist() == []  # folder query 10 -> rows 7..9: not in validation
    assert val.right_rows(3).tolist() == [0, 1, 2]  # folder query 13 -> rows 10..12


def test_file_ground_truth_survives_the_store_and_reaches_the_evaluation(seasons, tmp_path):
    gt = vpr_bench_file(tmp_path / "gt.npy", [[q] for q in range(N)])
    images, frames, meta = build_folder_dataset(file_config(seasons, gt), seed=0)
    save_dataset(tmp_path / "dataset", images, frames, meta)
    dataset = load_dataset(tmp_path / "dataset")
    _, test_frames = dataset.test()
    kind = dataset_ground_truth(dataset.meta)
    ref = test_frames.iloc[drive_rows(test_frames, "line/summer")]
    query = test_frames.iloc[drive_rows(test_frames, "line/winter")]
    sets = ground_truth_for_pair(ref, query, kind=kind, pose_tolerance=1.0)
    assert isinstance(sets, ReferenceSets) and sets.is_right(np.arange(12)).all()
    # query j looks like reference j + 1: one row off everywhere
    codes = np.random.default_rng(0).normal(size=(len(test_frames), 8))
    ref_rows, query_rows = (drive_rows(test_frames, d) for d in ("line/summer", "line/winter"))
    codes[query_rows[:-1]] = codes[ref_rows[1:]]
    results = {}
    for truth_kind in (kind, "index"):
        [(_, _, results[str(type(truth_kind))])] = evaluate_drive_pairs(
            codes, test_frames, dataset.pairs("test"), metric="sqeuclidean",
            params=SeqSLAMParams.defaults(ds=3, enhance=False), d_thresh=20, ground_truth=truth_kind,
            pose_tolerance=1.0, progress=None)
    by_file, by_index = results[str(dict)], results[str(str)]
    assert isinstance(by_file.truth, ReferenceSets)
    # by index, d_thresh=20 accepts a row one off; the file accepts only the listed row
    assert by_index.metrics["recall_at_1"] == 1.0
    match = by_file.result.match
    scored = match >= 0
    assert by_file.metrics["recall_at_1"] == pytest.approx(
        np.mean(match[scored] == np.arange(12)[scored]))
    assert by_file.metrics["recall_at_1"] < 0.2


def test_utm_names_in_the_pipeline(seasons, tmp_path):
    for season in ("summer", "winter"):
        for i, path in enumerate(sorted((tmp_path / season).iterdir())):
            name = (f"@{500000 + 10.0 * i:010.2f}@{4100000.0:010.2f}@10@S@@@@@@@@@"
                    f"20200101_12{i:02d}00@@.png")
            path.rename(path.with_name(name))
    cfg = config(seasons, **{"ground_truth": "utm", "positive_dist_threshold": 12.0,
                             "train.range": [1, 10], "test.range": [19, None]})
    _, _, meta = build_folder_dataset(cfg, seed=0)
    test = dataset_ground_truth(meta)[("line/summer", "line/winter")]
    assert test.right_rows(5).tolist() == [4, 5, 6]  # 10 m apart: neighbours within 12 m
    assert meta["ground_truth_source"]["tolerance"].startswith("12 m")


@pytest.mark.parametrize("changes, message", [
    ({"ground_truth_file": None}, "data.ground_truth_file: required"),
    ({"ground_truth_file": "missing.npy"}, "data.ground_truth_file: ground truth .*missing.npy: "
                                           "no such file"),
])
def test_bad_ground_truth_file_settings(seasons, tmp_path, changes, message):
    gt = vpr_bench_file(tmp_path / "gt.npy", [[q] for q in range(N)])
    cfg = file_config(seasons, gt)
    cfg.update(changes)
    with pytest.raises(FolderDatasetError, match=message):
        build_folder_dataset(cfg, seed=0)


def test_file_for_other_frame_counts_is_refused(seasons, tmp_path):
    gt = vpr_bench_file(tmp_path / "gt.npy", [[q] for q in range(N - 1)])
    with pytest.raises(FolderDatasetError, match=r"29 query rows, but there are 30 query"):
        build_folder_dataset(file_config(seasons, gt), seed=0)



def test_msls_drive_sequences_restart_where_the_selection_skips_a_frame(tmp_path):
    from cmal_lcd.data.folders import drive_sequence_starts
    from cmal_lcd.data.frames import list_frame_files

    side = tmp_path / "database"
    (side / "images").mkdir(parents=True)
    rows = [("k%02d" % i, "A" if i < 6 else "B", i if i < 6 else i - 6) for i in range(10)]
    for key, _, _ in rows:
        (side / "images" / f"{key}.jpg").write_bytes(b"listed, never decoded here")
    lines = [",key,sequence_key,frame_number"] + [f"{i},{k},{s},{n}"
                                                  for i, (k, s, n) in enumerate(rows)]
    (side / "seq_info.csv").write_text("\n".join(lines) + "\n")
    listed = list_frame_files(side)
    assert drive_sequence_starts(side, listed, listed) == [0, 6]
    selected = listed[2:5] + listed[6:10]  # frame 5 left out: drive A's run ends at 4
    assert drive_sequence_starts(side, listed, selected) == [0, 3]
    selected = listed[1:3] + listed[4:8]  # a gap inside drive A starts a new sequence
    assert drive_sequence_starts(side, listed, selected) == [0, 2, 4]
    assert drive_sequence_starts(tmp_path, listed, listed) is None  # not an MSLS side
