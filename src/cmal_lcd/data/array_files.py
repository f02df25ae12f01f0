"""Named arrays from the file formats of the field: ``.npy``, ``.npz``, ``.mat``, ``.h5``.

Descriptor files (:mod:`cmal_lcd.data.descriptors`) and ground-truth files
(:mod:`cmal_lcd.data.gt_files`) are read through :func:`read_arrays`, which returns
every array of a file under a name:

=================  =====================================================================
file               names
=================  =====================================================================
``.npy``           ``""`` (the one array). Object arrays (VPR-Bench's
                   ``ground_truth_new.npy``) are unpickled by :func:`load_object_npy`, which
                   only rebuilds NumPy arrays, lists, tuples, ranges and numbers: a pickle
                   that names anything else is refused, never run.
``.npz``           its keys (``np.load(..., allow_pickle=False)``).
``.mat`` v5        its variables (:func:`scipy.io.loadmat`); the fields of a struct as
                   ``struct.field`` (``GT.GThard``); sparse matrices stay SciPy sparse.
``.mat`` v7.3,     their datasets by HDF5 path with ``/`` written ``.`` (``GT.GThard``),
``.h5``, ``.hdf5`` through h5py. Datasets written by MATLAB (``MATLAB_class`` attribute) are
                   transposed back to MATLAB's shape (HDF5 stores MATLAB's column-major
                   arrays reversed), MATLAB sparse groups become SciPy sparse matrices.
=================  =====================================================================

Every problem raises :class:`ArrayFileError` (a ``ValueError``) naming the file.
"""

from __future__ import annotations

import io
import os
import pickle
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

#: Suffixes read (lower case).
ARRAY_SUFFIXES = (".npy", ".npz", ".mat", ".h5", ".hdf5")

#: ``(module, name)`` pairs an object ``.npy`` may name in its pickle: NumPy's array
#: reconstruction and scalars (``numpy.core`` before NumPy 2, ``numpy._core`` after) and the
#: built-in containers VPR-Bench stores (lists of indices, ``range`` objects).
_SAFE_GLOBALS = frozenset(
    [(core, name) for core in ("numpy.core.multiarray", "numpy._core.multiarray")
     for name in ("_reconstruct", "scalar")]
    + [("numpy", "ndarray"), ("numpy", "dtype"), ("builtins", "range"),
       ("builtins", "list"), ("builtins", "tuple"), ("builtins", "int"),
       ("builtins", "float"), ("builtins", "slice")])


class ArrayFileError(ValueError):
    """An array file cannot be read, or holds no usable array."""


def is_array_file(path: str | os.PathLike) -> bool:
    """Whether ``path`` names an array file by its suffix (:data:`ARRAY_SUFFIXES`)."""
    return Path(path).suffix.lower() in ARRAY_SUFFIXES


def read_arrays(path: str | os.PathLike) -> dict[str, Any]:
    """Every array of ``path`` by name (module table): NumPy arrays or SciPy sparse matrices.

    Raises
    ------
    ArrayFileError
        Missing file, a folder, an unknown suffix, an unreadable or corrupt file, an unsafe
        pickle.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in ARRAY_SUFFIXES:
        raise ArrayFileError(f"{path}: not an array file (expected one of "
                             f"{', '.join(ARRAY_SUFFIXES)})")
    if not path.exists():
        raise ArrayFileError(f"{path}: no such file")
    if not path.is_file():
        raise ArrayFileError(f"{path}: not a regular file")
    try:
        if suffix == ".npy":
            return {"": _read_npy(path)}
        if suffix == ".npz":
            with np.load(path, allow_pickle=False) as archive:
                return {key: archive[key] for key in archive.files}
        if suffix == ".mat" and not _is_hdf5(path):
            return _read_mat_v5(path)
        return _read_hdf5(path)
    except ArrayFileError:
        raise
    except (OSError, ValueError, EOFError, KeyError, IndexError, TypeError,
            NotImplementedError, pickle.UnpicklingError, zipfile.BadZipFile,
            _mat_read_error()) as err:
        raise ArrayFileError(f"{path}: cannot read it as {suffix} "
                             f"({type(err).__name__}: {_first_line(err)})") from None


def load_object_npy(data: bytes, *, name: str = "<bytes>") -> np.ndarray:
    """An ``.npy`` file's array from its bytes, object arrays through a restricted unpickler
    (only :data:`_SAFE_GLOBALS`; VPR-Bench ground truth needs nothing else)."""
    stream = io.BytesIO(data)
    version = np.lib.format.read_magic(stream)
    readers = {(1, 0): np.lib.format.read_array_header_1_0,
               (2, 0): np.lib.format.read_array_header_2_0}
    if version not in readers:
        raise ArrayFileError(f"{name}: .npy format version {version[0]}.{version[1]} is not "
                             f"read (1.0 and 2.0 are)")
    shape, _fortran, dtype = readers[version](stream)
    if not dtype.hasobject:
        stream.seek(0)
        return np.load(stream, allow_pickle=False)
    array = _SafeUnpickler(stream, name=name).load()
    if not isinstance(array, np.ndarray) or array.shape != shape:
        raise ArrayFileError(f"{name}: the pickled array does not match the header's shape "
                             f"{shape}")
    return array


class _SafeUnpickler(pickle.Unpickler):
    def __init__(self, stream, *, name: str):
        super().__init__(stream)
        self._name = name

    def find_class(self, module: str, name: str):
        if (module, name) not in _SAFE_GLOBALS:
            raise ArrayFileError(f"{self._name}: its pickle names {module}.{name}; only NumPy "
                                 f"arrays, lists, ranges and numbers are read from object "
                                 f"arrays (nothing in the file is run)")
        return super().find_class(module, name)


def _read_npy(path: Path) -> np.ndarray:
    with open(path, "rb") as handle:
        magic = handle.read(6)
    if magic != b"\x93NUMPY":
        raise ArrayFileError(f"{path}: not a NumPy .npy file (no .npy header)")
    return load_object_npy(path.read_bytes(), name=str(path))


def _mat_read_error() -> type[Exception]:
    """SciPy's ``MatReadError`` (raised for files that are not MATLAB files)."""
    from scipy.io.matlab import MatReadError

    return MatReadError


def _is_hdf5(path: Path) -> bool:
    """MATLAB v7.3 files are HDF5 (signature at byte 0 or after a 512-byte user block)."""
    signature = b"\x89HDF\r\n\x1a\n"
    with open(path, "rb") as handle:
        head = handle.read(520)
    return head[:8] == signature or head[512:520] == signature


def _read_mat_v5(path: Path) -> dict[str, Any]:
    import scipy.io

    variables = scipy.io.loadmat(path, squeeze_me=False, struct_as_record=True)
    out: dict[str, Any] = {}
    for name, value in variables.items():
        if not name.startswith("__"):
            _flatten_mat(name, value, out)
    return out


def _flatten_mat(name: str, value: Any, out: dict[str, Any]) -> None:
    """Put ``value`` under ``name``, a 1x1 struct's fields under ``name.field``."""
    if isinstance(value, np.ndarray) and value.dtype.names and value.size == 1:
        for field in value.dtype.names:
            _flatten_mat(f"{name}.{field}", value.reshape(-1)[0][field], out)
    else:
        out[name] = value


def _read_hdf5(path: Path) -> dict[str, Any]:
    import h5py

    out: dict[str, Any] = {}
    with h5py.File(path, "r") as handle:
        def visit(name: str, node) -> None:
            key = name.replace("/", ".")
            if isinstance(node, h5py.Group) and "MATLAB_sparse" in node.attrs:
                out[key] = _matlab_sparse(node)
            elif isinstance(node, h5py.Dataset) and not _inside_sparse(name, handle):
                if node.dtype.kind not in "biuf":  # references, strings: not arrays of ours
                    return
                value = node[()]
                out[key] = np.asarray(value).T if "MATLAB_class" in node.attrs else value
        handle.visititems(visit)
    return out


def _inside_sparse(name: str, handle) -> bool:
    parent = name.rsplit("/", 1)[0] if "/" in name else ""
    return bool(parent) and "MATLAB_sparse" in handle[parent].attrs


def _matlab_sparse(group):
    """A MATLAB v7.3 sparse matrix (``data``, ``ir``, ``jc``; ``MATLAB_sparse`` = rows) as
    a SciPy CSC matrix of MATLAB's shape."""
    import scipy.sparse

    n_rows = int(np.asarray(group.attrs["MATLAB_sparse"]).reshape(-1)[0])
    jc = np.asarray(group["jc"][()], dtype=np.int64)
    ir = np.asarray(group["ir"][()], dtype=np.int64) if "ir" in group else np.zeros(0, np.int64)
    data = (np.asarray(group["data"][()]) if "data" in group
            else np.ones(ir.size, dtype=bool))
    return scipy.sparse.csc_matrix((data, ir, jc), shape=(n_rows, jc.size - 1))


def _first_line(err: BaseException) -> str:
    text = str(err).strip().splitlines()
    return text[0] if text else ""
