"""Ground-truth files of the field: VPR-Bench rows, VPR_Tutorial GThard/GTsoft matrices."""

import numpy as np
import pytest
import scipy.sparse

from cmal_lcd.data.gt_files import (GroundTruthFileError, describe_ground_truth,
                                          read_ground_truth_file)
from mat_files import save_mat_v5, save_mat_v73


def vpr_bench_rows(lists) -> np.ndarray:
    rows = np.empty((len(lists), 2), dtype=object)
    for q, references in enumerate(lists):
        rows[q, 0], rows[q, 1] = q, references
    return rows


def test_vpr_bench_rows_lists_and_ranges(tmp_path):
    np.save(tmp_path / "gt.npy", vpr_bench_rows([[0, 1], range(1, 4), []]), allow_pickle=True)
    sets = read_ground_truth_file(tmp_path / "gt.npy", n_reference=5, n_query=3)
    assert [sets.right_rows(q).tolist() for q in range(3)] == [[0, 1], [1, 2, 3], []]
    described = describe_ground_truth(sets)
    assert described["source"].startswith("VPR-Bench ground_truth_new.npy: ")
    assert described["n_query_without_reference"] == 1 and described["n_right_pairs"] == 5


def test_vpr_bench_rows_must_be_in_query_order(tmp_path):
    rows = vpr_bench_rows([[0], [1]])
    rows[1, 0] = 7
    np.save(tmp_path / "gt.npy", rows, allow_pickle=True)
    with pytest.raises(GroundTruthFileError, match="row 1 names query 7"):
        read_ground_truth_file(tmp_path / "gt.npy", n_reference=2, n_query=2)


@pytest.mark.parametrize("n_reference, n_query, message", [
    (5, 4, "3 query rows, but there are 4 query frames"),
    (2, 3, r"reference index 3 outside 0..1 \(2 reference frames"),
])
def test_vpr_bench_sizes_checked(tmp_path, n_reference, n_query, message):
    np.save(tmp_path / "gt.npy", vpr_bench_rows([[0], [1], [3]]), allow_pickle=True)
    with pytest.raises(GroundTruthFileError, match=message):
        read_ground_truth_file(tmp_path / "gt.npy", n_reference=n_reference, n_query=n_query)


@pytest.mark.parametrize("save, suffix", [
    (save_mat_v5, ".mat"), (save_mat_v73, ".mat"),
    (lambda path, arrays: np.savez(path, **arrays["GT"]), ".npz"),
], ids=["mat-v5", "mat-v7.3", "npz"])
def test_gt_matrices_in_every_container(tmp_path, save, suffix):
    rng = np.random.default_rng(0)
    hard = rng.random((8, 5)) < 0.3
    soft = hard | (rng.random((8, 5)) < 0.3)
    path = tmp_path / f"gt{suffix}"
    save(path, {"GT": {"GThard": hard, "GTsoft": soft}})
    sets = read_ground_truth_file(path, n_reference=8, n_query=5)
    rows = np.tile(np.arange(8), (5, 1))  # every reference row of every query
    assert np.array_equal(sets.is_right(rows), hard.T)
    assert np.array_equal(sets.is_ignored(rows), (soft & ~hard).T)
    assert "GTsoft-only entries ignored" in sets.tolerance


def test_sparse_gthard_alone(tmp_path):
    hard = np.eye(6, dtype=bool)
    save_mat_v73(tmp_path / "gt.mat", {"GThard": scipy.sparse.csc_matrix(hard)})
    sets = read_ground_truth_file(tmp_path / "gt.mat", n_reference=6, n_query=6)
    assert sets.is_right(np.arange(6)).all() and sets.tolerance == "GThard as given (no GTsoft)"


def test_transposed_matrix_gets_a_hint(tmp_path):
    np.savez(tmp_path / "gt.npz", GThard=np.zeros((4, 6), bool))
    with pytest.raises(GroundTruthFileError, match="looks transposed"):
        read_ground_truth_file(tmp_path / "gt.npz", n_reference=6, n_query=4)


def test_neither_format_lists_what_the_file_holds(tmp_path):
    np.savez(tmp_path / "gt.npz", something=np.zeros((2, 2)))
    with pytest.raises(GroundTruthFileError, match=r"neither VPR-Bench rows nor a GThard "
                                                   r"matrix \(it holds something\)"):
        read_ground_truth_file(tmp_path / "gt.npz", n_reference=2, n_query=2)


def test_vpr_bench_corridor_file(corridor_dir):
    sets = read_ground_truth_file(corridor_dir / "ground_truth_new.npy", n_reference=111,
                                  n_query=111)
    assert sets.has_place().all()
    # about +-2 frames around the same index (README of the data folder)
    for q in (0, 55, 110):
        rows = sets.right_rows(q)
        assert q in rows and rows.min() >= q - 2 and rows.max() <= q + 2
