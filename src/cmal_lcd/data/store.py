"""The dataset on disk: ``images.npy`` + ``frames.csv`` + ``dataset.json`` (one folder).

- ``images.npy``: all frames as one ``uint8 (N, H, W, 3)`` RGB array, row = ``frame``. One
  ``.npy`` file is memory-mapped in milliseconds and sliced without decoding (tens of
  thousands of PNGs take seconds to decode on every training run); it is also one DVC object.
- ``frames.csv``: one row per frame, columns :data:`FRAME_COLUMNS` (see docs/architecture.md):
  ``x, y`` in metres (``x`` east, ``y`` north), ``heading`` in radians counter-clockwise from
  ``+x``, ``time`` in seconds since the drive's start, ``s`` the arc length along the route in
  metres; ``route`` and ``drive`` are empty strings and ``time``, ``s`` NaN for training frames.
- ``dataset.json``: ``kind``, ``image_size``, ``conditions`` (label order), ``routes``,
  ``drives``, ``pairs`` (``[route, reference_drive, query_drive, name]``), the config used.

Ground truth between two drives comes from their poses
(:func:`cmal_lcd.data.ground_truth.ground_truth_from_poses` on the ``x, y`` columns).
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import pandas as pd

from cmal_lcd.io import atomic_path, atomic_save_npy, atomic_write_json
from cmal_lcd.names import check_dataset_names
from cmal_lcd.paths import REPO

logger = logging.getLogger(__name__)

IMAGES_FILE = "images.npy"
FRAMES_FILE = "frames.csv"
META_FILE = "dataset.json"
FRAME_COLUMNS = ("frame", "split", "route", "drive", "condition", "x", "y", "heading", "time",
                 "s")
_TEXT_COLUMNS = ("split", "route", "drive", "condition")
_FLOAT_COLUMNS = ("x", "y", "heading", "time", "s")
SPLITS = ("train", "test", "val")


@dataclass(frozen=True)
class Dataset:
    """A loaded dataset.

    Attributes
    ----------
    path : Path
    images : ndarray, uint8 (N, H, W, 3)
        Memory-mapped, read-only.
    frames : pandas.DataFrame
        ``N`` rows, columns :data:`FRAME_COLUMNS`; row ``i`` describes ``images[i]``.
    meta : dict
        The content of ``dataset.json``.
    """

    path: Path
    images: np.ndarray
    frames: pd.DataFrame
    meta: dict

    def __len__(self) -> int:
        return len(self.frames)

    @property
    def conditions(self) -> list[str]:
        """Condition names in label order."""
        return list(self.meta["conditions"])

    def select(self, mask: np.ndarray) -> tuple[np.ndarray, pd.DataFrame]:
        """Images and frame rows where ``mask`` is true, in frame order.

        A contiguous run of rows is returned as a memory-mapped view (no copy); otherwise the
        images are gathered into memory. The frames' index is reset to ``0 .. n-1``.

        Parameters
        ----------
        mask : ndarray, bool (N,)

        Returns
        -------
        images : ndarray, uint8 (n, H, W, 3)
        frames : pandas.DataFrame
        """
        rows = np.flatnonzero(np.asarray(mask, bool))
        if len(rows) and rows[-1] - rows[0] + 1 == len(rows):
            images = self.images[rows[0]:rows[-1] + 1]
        else:
            images = self.images[rows]
        return images, self.frames.iloc[rows].reset_index(drop=True)

    def split(self, name: str) -> tuple[np.ndarray, pd.DataFrame]:
        """Images and frames of the split ``name`` (``"train"``, ``"test"`` or ``"val"``)."""
        if name not in SPLITS:
            raise ValueError(f"name: unknown split {name!r}; known: {list(SPLITS)}")
        return self.select(self.frames["split"].to_numpy() == name)

    def train(self) -> tuple[np.ndarray, pd.DataFrame]:
        """Images and frames of the training split."""
        return self.split("train")

    def test(self) -> tuple[np.ndarray, pd.DataFrame]:
        """Images and frames of the test split (every drive, in frame order)."""
        return self.split("test")

    def validation(self) -> tuple[np.ndarray, pd.DataFrame]:
        """Images and frames of the validation split (empty when the dataset has none)."""
        return self.split("val")

    def pairs(self, split: str = "test") -> list[list[str]]:
        """``[route, reference_drive, query_drive, pair]`` of ``split`` (``test`` or ``val``)."""
        if split not in ("test", "val"):
            raise ValueError(f"split: expected 'test' or 'val', got {split!r}")
        return [list(p) for p in self.meta.get("pairs" if split == "test"
                                               else "validation_pairs", [])]

    def drive(self, name: str) -> tuple[np.ndarray, pd.DataFrame]:
        """Images and frames of one drive (e.g. ``"route1/foggy"``), in time order."""
        mask = self.frames["drive"].to_numpy() == name
        if not mask.any():
            known = sorted(set(self.frames["drive"]) - {""})
            raise ValueError(f"name: no drive {name!r} in {self.path}; known: {known}")
        return self.select(mask)

    def ground_truth(self, reference_drive: str, query_drive: str, *,
                     max_distance: float) -> np.ndarray:
        """True place of every frame of ``query_drive`` in ``reference_drive``, from poses.

        Returns
        -------
        ndarray, int64 (Q,)
            Index (within the reference drive) of the nearest reference pose, ``-1`` when it is
            farther than ``max_distance`` metres
            (:func:`cmal_lcd.data.ground_truth.ground_truth_from_poses`).
        """
        from cmal_lcd.data.ground_truth import ground_truth_from_poses

        _, reference = self.drive(reference_drive)
        _, query = self.drive(query_drive)
        return ground_truth_from_poses(reference[["x", "y"]].to_numpy(np.float64),
                                       query[["x", "y"]].to_numpy(np.float64),
                                       max_distance=max_distance)

    def condition_index(self, name: str) -> int:
        """Label of condition ``name``: its position in ``meta["conditions"]``."""
        try:
            return self.conditions.index(name)
        except ValueError:
            raise ValueError(f"name: unknown condition {name!r}; "
                             f"known: {self.conditions}") from None


def read_frames(path: str | Path) -> pd.DataFrame:
    """Read a ``frames.csv`` with the column types of :data:`FRAME_COLUMNS`.

    Text columns keep empty strings (not NaN); empty numeric cells are NaN.
    """
    path = Path(path)
    frames = pd.read_csv(path, dtype={c: str for c in _TEXT_COLUMNS}, keep_default_na=False,
                         na_values={c: [""] for c in _FLOAT_COLUMNS})
    if tuple(frames.columns) != FRAME_COLUMNS:
        raise ValueError(f"{path}: expected columns {list(FRAME_COLUMNS)}, "
                         f"got {list(frames.columns)}")
    frames["frame"] = frames["frame"].astype(np.int64)
    for column in _FLOAT_COLUMNS:
        frames[column] = frames[column].astype(np.float64)
    return frames


def load_dataset(path: str | Path | None = None) -> Dataset:
    """Load a dataset folder written by :func:`save_dataset`.

    Raises
    ------
    FileNotFoundError
        When a file of the folder is missing.
    ValueError
        When the files disagree (row counts, frame ids, image size), or ``dataset.json`` holds
        an unsafe route, condition, drive or pair name (names reach file names:
        :func:`cmal_lcd.names.check_dataset_names`).
    """
    path = Path(path) if path is not None else REPO.dataset
    for name in (IMAGES_FILE, FRAMES_FILE, META_FILE):
        if not (path / name).is_file():
            raise FileNotFoundError(f"{path / name}: no such file (run the dataset stage)")
    images = np.load(path / IMAGES_FILE, mmap_mode="r")
    frames = read_frames(path / FRAMES_FILE)
    meta = json.loads((path / META_FILE).read_text(encoding="utf-8"))
    check_dataset_names(meta, where=str(path / META_FILE))
    _check(images, frames, meta, where=str(path))
    return Dataset(path=path, images=images, frames=frames, meta=meta)


def save_dataset(path: str | Path, images: np.ndarray, frames: pd.DataFrame,
                 meta: Mapping[str, Any]) -> Path:
    """Write a dataset folder; each file is written atomically, ``dataset.json`` last.

    Parameters
    ----------
    path : str or Path
        The folder (created).
    images : ndarray, uint8 (N, H, W, 3)
    frames : pandas.DataFrame
        ``N`` rows, columns :data:`FRAME_COLUMNS`, ``frame == 0 .. N-1``.
    meta : mapping
        At least ``conditions`` (list), ``routes`` (list), ``pairs`` (list) and ``image_size``.

    Returns
    -------
    Path
        The folder.

    Raises
    ------
    ValueError
        Naming the argument that is inconsistent, or an unsafe name in ``meta``.
    """
    path = Path(path)
    meta = dict(meta)
    images = np.asarray(images)
    if tuple(frames.columns) != FRAME_COLUMNS:
        raise ValueError(f"frames: expected columns {list(FRAME_COLUMNS)}, "
                         f"got {list(frames.columns)}")
    check_dataset_names(meta, where="save_dataset")
    _check(images, frames, meta, where="save_dataset")
    path.mkdir(parents=True, exist_ok=True)
    atomic_save_npy(path / IMAGES_FILE, images)
    with atomic_path(path / FRAMES_FILE) as tmp:
        frames.to_csv(tmp, index=False, lineterminator="\n")
    atomic_write_json(path / META_FILE, meta)
    logger.info("wrote %s: %d frames of %s", path, len(frames), list(images.shape[1:3]))
    return path


def _check(images: np.ndarray, frames: pd.DataFrame, meta: Mapping[str, Any], *,
           where: str) -> None:
    """The three parts of a dataset agree."""
    if images.dtype != np.uint8 or images.ndim != 4 or images.shape[-1] != 3:
        raise ValueError(f"{where}: images must be uint8 (N, H, W, 3), got {images.dtype} "
                         f"{images.shape}")
    if len(frames) != len(images):
        raise ValueError(f"{where}: {len(frames)} frame rows for {len(images)} images")
    if not np.array_equal(frames["frame"].to_numpy(), np.arange(len(frames))):
        raise ValueError(f"{where}: the frame column must be 0 .. N-1 in row order")
    for key in ("conditions", "routes", "pairs", "image_size"):
        if key not in meta:
            raise ValueError(f"{where}: meta lacks the key {key!r}")
    if list(meta["image_size"]) != list(images.shape[1:3]):
        raise ValueError(f"{where}: meta image_size {list(meta['image_size'])} but images are "
                         f"{list(images.shape[1:3])}")
    splits = set(frames["split"])
    if not splits <= set(SPLITS):
        raise ValueError(f"{where}: unknown splits {sorted(splits - set(SPLITS))}")
    unknown = set(frames["condition"]) - set(meta["conditions"])
    if unknown:
        raise ValueError(f"{where}: frames name conditions not in meta: {sorted(unknown)}")
