"""Arrays from .npy, .npz, .mat (v5, v7.3) and .h5 files; descriptors read from them."""

import h5py
import numpy as np
import pytest
import scipy.sparse

from cmal_lcd.data.array_files import ArrayFileError, read_arrays
from cmal_lcd.data.descriptors import read_descriptors
from mat_files import save_mat_v5, save_mat_v73


@pytest.fixture
def matrix():
    return np.random.default_rng(0).normal(size=(7, 5)).astype(np.float32)


@pytest.mark.parametrize("save", [save_mat_v5, save_mat_v73], ids=["v5", "v7.3"])
def test_mat_files_keep_matlab_shapes_and_struct_fields(tmp_path, matrix, save):
    hard = np.random.default_rng(1).random((6, 4)) < 0.3
    path = tmp_path / "x.mat"
    save(path, {"Y": matrix, "GT": {"GThard": hard, "GTsoft": hard | np.eye(6, 4, dtype=bool)}})
    arrays = read_arrays(path)
    assert set(arrays) == {"Y", "GT.GThard", "GT.GTsoft"}
    assert np.array_equal(arrays["Y"], matrix)  # MATLAB's 7 x 5, not HDF5's 5 x 7
    assert np.array_equal(arrays["GT.GThard"].astype(bool), hard)


@pytest.mark.parametrize("save", [save_mat_v5, save_mat_v73], ids=["v5", "v7.3"])
def test_sparse_matrices_come_back_sparse(tmp_path, save):
    dense = np.random.default_rng(2).random((9, 6)) < 0.2
    path = tmp_path / "s.mat"
    save(path, {"GThard": scipy.sparse.csc_matrix(dense)})
    value = read_arrays(path)["GThard"]
    assert scipy.sparse.issparse(value) and value.shape == (9, 6)
    assert np.array_equal(value.toarray().astype(bool), dense)


def test_npy_npz_and_h5_by_name(tmp_path, matrix):
    np.save(tmp_path / "a.npy", matrix)
    np.savez(tmp_path / "b.npz", first=matrix, second=matrix[:2])
    with h5py.File(tmp_path / "c.h5", "w") as handle:  # Python's own HDF5: no transpose
        handle.create_dataset("group/descriptors", data=matrix)
    assert np.array_equal(read_arrays(tmp_path / "a.npy")[""], matrix)
    assert set(read_arrays(tmp_path / "b.npz")) == {"first", "second"}
    assert np.array_equal(read_arrays(tmp_path / "c.h5")["group.descriptors"], matrix)


def test_object_npy_runs_nothing(tmp_path):
    class Evil:
        def __reduce__(self):
            return (open, (str(tmp_path / "PWNED"), "w"))

    array = np.empty(2, dtype=object)
    array[:] = [Evil(), [1, 2]]
    np.save(tmp_path / "evil.npy", array, allow_pickle=True)
    with pytest.raises(ArrayFileError, match=r"evil\.npy: its pickle names .*open"):
        read_arrays(tmp_path / "evil.npy")
    assert not (tmp_path / "PWNED").exists()


def test_object_npy_of_lists_and_ranges(tmp_path):
    array = np.empty((2, 2), dtype=object)
    array[0] = [0, [0, 1]]
    array[1] = [1, range(0, 3)]
    np.save(tmp_path / "gt.npy", array, allow_pickle=True)
    back = read_arrays(tmp_path / "gt.npy")[""]
    assert back.shape == (2, 2) and list(back[1][1]) == [0, 1, 2]


@pytest.mark.parametrize("name, content, message", [
    ("missing.npy", None, "no such file"),
    ("x.txt", b"1 2 3", "not an array file"),
    ("bad.npy", b"not numpy at all", "not a NumPy .npy file"),
    ("bad.npz", b"PK\x03\x04 truncated", "cannot read it as .npz"),
    ("bad.mat", b"MATLAB 5.0 MAT-file" + b"\0" * 20, "cannot read it as .mat"),
    ("bad.h5", b"\x89HDF\r\n\x1a\n" + b"\0" * 40, "cannot read it as .h5"),
])
def test_bad_files_are_named(tmp_path, name, content, message):
    path = tmp_path / name
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(ArrayFileError, match=message) as caught:
        read_arrays(path)
    assert str(path) in str(caught.value) and "\n" not in str(caught.value)


# ---------------------------------------------------------------------------- descriptors


def test_descriptors_by_key_or_the_only_2d_array(tmp_path, matrix):
    # a MATLAB char array is not numeric: Y is the file's only 2-D numeric array
    save_mat_v5(tmp_path / "d.mat", {"Y": matrix, "names": np.array(["frame one"])})
    assert np.array_equal(read_descriptors(tmp_path / "d.mat"), matrix)
    np.savez(tmp_path / "two.npz", a=matrix, b=matrix)
    with pytest.raises(ArrayFileError, match=r"several 2-D arrays .*--descriptor-key"):
        read_descriptors(tmp_path / "two.npz")
    assert np.array_equal(read_descriptors(tmp_path / "two.npz", key="b"), matrix)
    with pytest.raises(ArrayFileError, match=r"no array named 'c' \(it holds a \(7, 5\), b"):
        read_descriptors(tmp_path / "two.npz", key="c")


def test_descriptors_float64_kept_others_float32(tmp_path):
    np.save(tmp_path / "f64.npy", np.ones((3, 2)))
    np.save(tmp_path / "u8.npy", np.ones((3, 2), np.uint8))
    assert read_descriptors(tmp_path / "f64.npy").dtype == np.float64
    assert read_descriptors(tmp_path / "u8.npy").dtype == np.float32


@pytest.mark.parametrize("array, message", [
    (np.ones(5), r"2-D \(frames, dimensions\) array, got shape \(5,\)"),
    (np.ones((0, 4)), "empty"),
    (np.ones((3, 2), bool), "real numbers, got bool"),
    (np.array([[1.0, 2.0], [np.nan, 1.0], [1.0, np.inf]]), r"row 1 \(and 1 more rows\) holds NaN"),
])
def test_bad_descriptors_are_named(tmp_path, array, message):
    np.save(tmp_path / "d.npy", array)
    with pytest.raises(ArrayFileError, match=message) as caught:
        read_descriptors(tmp_path / "d.npy")
    assert "d.npy" in str(caught.value)
