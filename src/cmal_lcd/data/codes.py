"""Reading the feature stage's output (``data/features/<method>/codes.npy`` + ``info.json``)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

REQUIRED_INFO_KEYS = ("method", "label", "metric", "dim", "bytes_per_frame")


def load_features(path: str | Path, *, expected_rows: int | None = None) -> tuple[np.ndarray, dict]:
    """Load a method's per-frame codes and their description.

    Parameters
    ----------
    path : path
        ``data/features/<method>/``.
    expected_rows : int, optional
        Number of test frames the codes must cover.

    Returns
    -------
    codes : ndarray (N, F)
        One row per test frame, in ``frames.csv`` order.
    info : dict
        ``method, label, metric, dim, bytes_per_frame, weights, timing``.

    Raises
    ------
    FileNotFoundError, ValueError
        Naming the file when it is missing, malformed, of the wrong size, or holds NaN/inf.
    """
    path = Path(path)
    codes_file, info_file = path / "codes.npy", path / "info.json"
    for file in (codes_file, info_file):
        if not file.is_file():
            raise FileNotFoundError(f"{file}: missing; run the extract_features stage")
    try:
        info = json.loads(info_file.read_text(encoding="utf-8"))
    except json.JSONDecodeError as err:
        raise ValueError(f"{info_file}: not valid JSON ({err})") from err
    missing = [k for k in REQUIRED_INFO_KEYS if k not in info]
    if missing:
        raise ValueError(f"{info_file}: missing keys {missing}")
    return _load_codes(codes_file, expected_rows=expected_rows, what="test frames"), info


def _load_codes(codes_file: Path, *, expected_rows: int | None, what: str) -> np.ndarray:
    """A 2-D codes array, checked for shape and finiteness (errors name the file)."""
    if not codes_file.is_file():
        raise FileNotFoundError(f"{codes_file}: missing; run the extract_features stage")
    try:
        codes = np.load(codes_file, allow_pickle=False)
    except (ValueError, EOFError, OSError) as err:
        raise ValueError(f"{codes_file}: not a readable .npy array, truncated or corrupt "
                         f"({err}); re-run extract_features") from err
    if codes.ndim != 2:
        raise ValueError(f"{codes_file}: expected a 2-D array (frames, dim), "
                         f"got shape {codes.shape}")
    if expected_rows is not None and codes.shape[0] != expected_rows:
        raise ValueError(f"{codes_file}: {codes.shape[0]} rows but the dataset has "
                         f"{expected_rows} {what}; re-run extract_features")
    if np.issubdtype(codes.dtype, np.floating):
        bad = ~np.isfinite(codes).all(axis=1)
        if bad.any():
            raise ValueError(f"{codes_file}: row {int(np.argmax(bad))} holds NaN or inf "
                             f"({int(bad.sum())} bad rows)")
    return codes


def load_validation_codes(path: str | Path, *, expected_rows: int | None = None) -> np.ndarray:
    """``val_codes.npy``: ``(V, F)``, one row per validation frame in ``frames.csv`` order."""
    return _load_codes(Path(path) / "val_codes.npy", expected_rows=expected_rows,
                       what="validation frames")


def load_training_codes(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """``train_codes.npy`` ``(M, F)`` and ``train_labels.npy`` ``int64 (M,)`` (condition index)."""
    path = Path(path)
    codes = _load_codes(path / "train_codes.npy", expected_rows=None, what="training frames")
    labels_file = path / "train_labels.npy"
    if not labels_file.is_file():
        raise FileNotFoundError(f"{labels_file}: missing; run the extract_features stage")
    try:
        labels = np.load(labels_file, allow_pickle=False)
    except (ValueError, EOFError, OSError) as err:
        raise ValueError(f"{labels_file}: not a readable .npy array ({err})") from err
    if labels.shape != (len(codes),) or not np.issubdtype(labels.dtype, np.integer):
        raise ValueError(f"{labels_file}: expected {len(codes)} integer labels, got "
                         f"{labels.dtype} {labels.shape}")
    return codes, labels.astype(np.int64)


def load_centring_means(path: str | Path, n_conditions: int) -> np.ndarray:
    """Training-set mean code per condition, ``(n_conditions, F)``, from a features folder's
    ``train_codes.npy`` / ``train_labels.npy`` (the statistics of ``centre="condition"``; see
    :func:`cmal_lcd.matching.normalise.condition_means`)."""
    from cmal_lcd.matching.normalise import condition_means

    codes, labels = load_training_codes(path)
    return condition_means(codes, labels, n_conditions)
