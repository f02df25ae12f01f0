"""Write MATLAB files as MATLAB does, for tests: v5 through SciPy, v7.3 as HDF5 by hand.

MATLAB v7.3 files are HDF5 files with a 512-byte user block; MATLAB writes each array
column-major, so HDF5 holds it with its dimensions reversed (a ``R x Q`` matrix is stored
``Q x R``), with a ``MATLAB_class`` attribute; a struct is a group of class ``struct``; a
sparse matrix is a group with ``data``, ``ir`` (row indices), ``jc`` (column starts) and a
``MATLAB_sparse`` attribute holding the number of rows.
"""

from __future__ import annotations

import h5py
import numpy as np
import scipy.io
import scipy.sparse


def save_mat_v5(path, variables: dict) -> None:
    """``variables``: name -> array, sparse matrix, or dict (a struct of such fields)."""
    scipy.io.savemat(path, variables, do_compression=True)


def save_mat_v73(path, variables: dict) -> None:
    """As :func:`save_mat_v5`, in MATLAB's v7.3 (HDF5) layout."""
    with h5py.File(path, "w", userblock_size=512) as handle:
        for name, value in variables.items():
            _write(handle, name, value)
    with open(path, "r+b") as raw:  # MATLAB's text header in the user block
        raw.write(b"MATLAB 7.3 MAT-file, written by cmal-lcd's tests".ljust(116, b" "))


def _write(group, name: str, value) -> None:
    if isinstance(value, dict):
        sub = group.create_group(name)
        sub.attrs["MATLAB_class"] = np.bytes_(b"struct")
        for field, item in value.items():
            _write(sub, field, item)
    elif scipy.sparse.issparse(value):
        csc = scipy.sparse.csc_matrix(value)
        sub = group.create_group(name)
        sub.attrs["MATLAB_class"] = np.bytes_(b"logical" if csc.dtype == bool else b"double")
        sub.attrs["MATLAB_sparse"] = np.uint64(csc.shape[0])
        sub.create_dataset("data", data=csc.data.astype(np.uint8 if csc.dtype == bool
                                                        else np.float64))
        sub.create_dataset("ir", data=csc.indices.astype(np.uint64))
        sub.create_dataset("jc", data=csc.indptr.astype(np.uint64))
    else:
        array = np.asarray(value)
        matlab_class = b"logical" if array.dtype == bool else (
            b"single" if array.dtype == np.float32 else b"double")
        stored = array.astype(np.uint8) if array.dtype == bool else array
        dataset = group.create_dataset(name, data=np.ascontiguousarray(stored.T))
        dataset.attrs["MATLAB_class"] = np.bytes_(matlab_class)
