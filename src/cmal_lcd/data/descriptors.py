"""Precomputed descriptors: one row per frame, in sequence order, from a user's file.

A researcher's own descriptors (NetVLAD, CosPlace, HDC-DELF, ...) come as ``.npy``, ``.npz``,
``.mat`` (v5 or v7.3) or ``.h5`` files (:mod:`cmal_lcd.data.array_files`). Which array:

- ``key`` when given (an ``.npz`` key, a MATLAB variable, ``struct.field``, an HDF5 path with
  ``.`` for ``/``);
- else the file's only two-dimensional numeric array (a ``.npy`` holds one).

The array is ``(frames, dimensions)``: row ``i`` is frame ``i`` of the sequence (in MATLAB's
own shape for ``.mat`` files, whatever HDF5 stores). Every problem raises
:class:`~cmal_lcd.data.array_files.ArrayFileError` (a ``ValueError``) naming the file and, where
one is at fault, the key or row.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from cmal_lcd.data.array_files import ArrayFileError, read_arrays


def read_descriptors(path: str | os.PathLike, *, key: str | None = None) -> np.ndarray:
    """The descriptors of ``path``: ``float32 (N, D)`` (``float64`` kept as it is).

    Raises
    ------
    ArrayFileError
        The file cannot be read; ``key`` is not in it; no key given and the file holds no or
        several 2-D numeric arrays; the array is not 2-D and numeric, is empty, or has a row
        with NaN or infinite values.
    """
    arrays = read_arrays(path)
    name, array = _chosen_array(Path(path), arrays, key=key)
    where = f"{path}" + (f" [{name}]" if name else "")
    if hasattr(array, "toarray"):  # SciPy sparse
        array = array.toarray()
    array = np.asarray(array)
    if array.ndim != 2:
        raise ArrayFileError(f"{where}: descriptors must be a 2-D (frames, dimensions) array, "
                             f"got shape {array.shape}")
    if array.dtype == np.bool_ or not np.issubdtype(array.dtype, np.number) \
            or np.issubdtype(array.dtype, np.complexfloating):
        raise ArrayFileError(f"{where}: descriptors must be real numbers, got {array.dtype}")
    if 0 in array.shape:
        raise ArrayFileError(f"{where}: descriptors are empty (shape {array.shape})")
    out = array if array.dtype == np.float64 else array.astype(np.float32)
    bad = np.flatnonzero(~np.isfinite(out).all(axis=1))
    if bad.size:
        more = f" (and {bad.size - 1} more rows)" if bad.size > 1 else ""
        raise ArrayFileError(f"{where}: row {int(bad[0])}{more} holds NaN or infinite values")
    return np.ascontiguousarray(out)


def _chosen_array(path: Path, arrays: dict, *, key: str | None):
    """``(name, array)``: ``key``'s array, else the one 2-D numeric array of the file."""
    if key is not None:
        if key not in arrays:
            raise ArrayFileError(f"{path}: no array named {key!r} (it holds "
                                 f"{_listing(arrays)})")
        return key, arrays[key]
    if list(arrays) == [""]:
        return "", arrays[""]
    candidates = {name: value for name, value in arrays.items()
                  if len(getattr(value, "shape", ())) == 2 and _numeric(value)}
    if len(candidates) == 1:
        return next(iter(candidates.items()))
    if not candidates:
        raise ArrayFileError(f"{path}: no 2-D numeric array (it holds {_listing(arrays)})")
    raise ArrayFileError(f"{path}: holds several 2-D arrays ({_listing(candidates)}); name one "
                         f"with --descriptor-key")


def _numeric(value) -> bool:
    dtype = getattr(value, "dtype", None)
    return dtype is not None and dtype != np.bool_ and np.issubdtype(dtype, np.number)


def _listing(arrays: dict) -> str:
    if not arrays:
        return "no arrays"
    return ", ".join(f"{name or '(the array)'} {tuple(getattr(value, 'shape', ()))}"
                     for name, value in sorted(arrays.items()))
