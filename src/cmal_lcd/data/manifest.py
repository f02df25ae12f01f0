"""Split manifests: exactly which frames a dataset used, and a check of a copy against one.

The ``dataset`` stage writes ``data/manifest.csv`` beside ``data/dataset/`` (a separate DVC
output, so the dataset's own hash never changes). One row per frame, columns
:data:`MANIFEST_COLUMNS`:

- ``frame``: row of ``images.npy`` / ``frames.csv`` (``-1`` for ``unused`` rows);
- ``split``: ``train``, ``val`` or ``test`` (as ``frames.csv``), or ``unused`` for a file of a
  source folder that no split selected (listed so that an inserted or deleted file, which
  would shift a position range, is detected);
- ``role``: ``reference``, ``query`` or both (``reference;query``) for test and validation
  drives, from the dataset's pairs; empty for training frames;
- ``index``: 0-based position of the frame within its drive (test/val) or condition (train);
- ``drive``, ``condition``: as ``frames.csv``;
- ``path``: for folder datasets, the source file relative to the data root (the common parent
  of ``data.train.dir`` and ``data.test.dir``, e.g. ``summer/images-00010.png``); empty for the
  rendered world;
- ``file_sha256``: sha256 of the source file's bytes (folder datasets; empty for ``unused``
  rows and the world);
- ``pixels_sha256``: sha256 of the stored frame, ``uint8 (H, W, 3)`` RGB in C order (every
  dataset; empty for ``unused`` rows).

:func:`verify_manifest` compares a manifest with a dataset folder (``images.npy``,
``frames.csv``: by frame id, pixels and labels) or with a data root of frame folders (by
``path``: file bytes; every file of the listed sub-folders must be in the manifest).
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np
import pandas as pd

#: Columns of a manifest, in order.
MANIFEST_COLUMNS = ("frame", "split", "role", "index", "drive", "condition", "path",
                    "file_sha256", "pixels_sha256")

_TEXT = ("split", "role", "drive", "condition", "path", "file_sha256", "pixels_sha256")


class ManifestError(ValueError):
    """A manifest, dataset or folder cannot be read or compared (bad input, not a mismatch)."""


def sha256_bytes(data: bytes) -> str:
    """Hex sha256 of ``data``."""
    return hashlib.sha256(data).hexdigest()


def pixels_sha256(image: np.ndarray) -> str:
    """Hex sha256 of one stored frame, ``uint8 (H, W, 3)``, C order."""
    return sha256_bytes(np.ascontiguousarray(image, dtype=np.uint8).tobytes())


def frame_roles(frames: pd.DataFrame, pairs: Sequence[Sequence[str]]) -> list[str]:
    """``reference``/``query``/``reference;query`` per frame from ``[route, ref, query, name]``
    pairs (test and validation); ``""`` for frames of no pair (training)."""
    roles: dict[str, set[str]] = {}
    for _, reference, query, *_ in pairs:
        roles.setdefault(reference, set()).add("reference")
        roles.setdefault(query, set()).add("query")
    return [";".join(sorted(roles.get(drive, ()))) for drive in frames["drive"]]


def build_manifest(images: np.ndarray, frames: pd.DataFrame, meta: dict, *,
                   files: Sequence[Path] | None = None, root: Path | None = None,
                   unused: Sequence[Path] = ()) -> pd.DataFrame:
    """The manifest of a dataset.

    Parameters
    ----------
    images : numpy.ndarray
        ``uint8 (N, H, W, 3)`` the stored frames.
    frames : pandas.DataFrame
        ``N`` rows, the store's frame table.
    meta : dict
        ``dataset.json`` content (``pairs``, ``validation_pairs``).
    files : sequence of Path, optional
        Source file of every frame, in row order (folder datasets).
    root : Path, optional
        Data root the ``path`` column is relative to (needed with ``files``).
    unused : sequence of Path
        Files of the source folders that no split selected (listed as ``unused``).

    Returns
    -------
    pandas.DataFrame
        Columns :data:`MANIFEST_COLUMNS`, used frames in row order, then ``unused`` files by
        path.
    """
    n = len(frames)
    if len(images) != n:
        raise ValueError(f"images: {len(images)} frames for {n} rows of frames")
    if files is not None and (len(files) != n or root is None):
        raise ValueError(f"files: expected {n} source files and a root, got {len(files)}")
    pairs = list(meta.get("pairs", [])) + list(meta.get("validation_pairs", []))
    table = _used_rows(images, frames, pairs, files=files, root=root)
    if len(unused):
        table = pd.concat([table, _unused_rows(unused, root)], ignore_index=True)
    return table


def _index_in_group(frames: pd.DataFrame) -> np.ndarray:
    """Position of each frame within its condition (training) or drive (others), int64 (N,)."""
    group = np.where(frames["split"].to_numpy() == "train", frames["condition"].to_numpy(),
                     frames["drive"].to_numpy())
    index = pd.Series(group).groupby(group, sort=False).cumcount().to_numpy()
    return index.astype(np.int64)


def _used_rows(images: np.ndarray, frames: pd.DataFrame, pairs: list, *,
               files: Sequence[Path] | None, root: Path | None) -> pd.DataFrame:
    """One manifest row per frame of ``frames`` (pixels from ``images`` uint8 (N, H, W, 3));
    ``path`` and ``file_sha256`` from ``files`` when given, else empty."""
    n = len(frames)
    index = _index_in_group(frames)
    return pd.DataFrame({
        "frame": frames["frame"].to_numpy(np.int64),
        "split": frames["split"].to_numpy(),
        "role": frame_roles(frames, pairs),
        "index": index,
        "drive": frames["drive"].to_numpy(),
        "condition": frames["condition"].to_numpy(),
        "path": [_relative(f, root) for f in files] if files is not None else [""] * n,
        "file_sha256": [sha256_bytes(Path(f).read_bytes()) for f in files]
        if files is not None else [""] * n,
        "pixels_sha256": [pixels_sha256(images[i]) for i in range(n)],
    }, columns=list(MANIFEST_COLUMNS))


def _unused_rows(unused: Sequence[Path], root: Path | None) -> pd.DataFrame:
    """The ``unused`` files as manifest rows (split ``unused``, frame -1), sorted by path."""
    paths = sorted(_relative(f, root) for f in unused)
    return pd.DataFrame({"frame": -1, "split": "unused", "role": "", "index": -1,
                         "drive": "", "condition": "", "path": paths, "file_sha256": "",
                         "pixels_sha256": ""}, columns=list(MANIFEST_COLUMNS))


def write_manifest(path: str | os.PathLike, manifest: pd.DataFrame) -> Path:
    """Write a manifest CSV atomically (``\\n`` line ends)."""
    from cmal_lcd.io import atomic_path

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        manifest.to_csv(tmp, index=False, lineterminator="\n")
    return path


def read_manifest(path: str | os.PathLike) -> pd.DataFrame:
    """Read a manifest CSV.

    Raises
    ------
    ManifestError
        Naming the file when it is missing, unparsable or lacks columns.
    """
    path = Path(path)
    if not path.is_file():
        raise ManifestError(f"{path}: no such manifest file")
    try:
        table = pd.read_csv(path, dtype={c: str for c in _TEXT}, keep_default_na=False)
    except (OSError, ValueError, pd.errors.ParserError) as exc:
        raise ManifestError(f"{path}: cannot parse the manifest ({exc})") from None
    if tuple(table.columns) != MANIFEST_COLUMNS:
        raise ManifestError(f"{path}: expected columns {list(MANIFEST_COLUMNS)}, got "
                            f"{list(table.columns)}")
    _check_frame_numbers(table, path)
    return table


def _check_frame_numbers(table: pd.DataFrame, path: Path) -> None:
    """Refuse a used row whose ``frame`` is not a non-negative integer, naming its line."""
    frame = pd.to_numeric(table["frame"], errors="coerce")
    good = frame.notna() & (frame == frame.round()) & (frame >= 0)
    bad = (table["split"] != "unused") & ~good
    if bad.any():
        row = int(np.flatnonzero(bad.to_numpy())[0])
        cell = str(table["frame"].iloc[row])
        raise ManifestError(f"{path}: line {row + 2}: frame {cell!r} is not a frame number (a "
                            f"non-negative integer)")


@dataclass
class Verification:
    """Outcome of :func:`verify_manifest`: lists of human-readable frame labels."""

    changed: list[str] = field(default_factory=list)
    missing: list[str] = field(default_factory=list)
    extra: list[str] = field(default_factory=list)
    checked: int = 0

    @property
    def ok(self) -> bool:
        """No changed, missing or extra frame."""
        return not (self.changed or self.missing or self.extra)

    def summary(self, *, limit: int = 10) -> str:
        """Lines: counts, then up to ``limit`` examples of each kind."""
        lines = [f"checked {self.checked} frames: {len(self.changed)} changed, "
                 f"{len(self.missing)} missing, {len(self.extra)} extra"]
        for kind, items in (("changed", self.changed), ("missing", self.missing),
                            ("extra", self.extra)):
            for item in items[:limit]:
                lines.append(f"  {kind}: {item}")
            if len(items) > limit:
                lines.append(f"  ... and {len(items) - limit} more {kind}")
        return "\n".join(lines)


def verify_manifest(manifest: pd.DataFrame, target: str | os.PathLike) -> Verification:
    """Compare a manifest with a dataset folder or a data root of frame folders.

    Parameters
    ----------
    manifest : pandas.DataFrame
        From :func:`read_manifest`.
    target : path-like
        A dataset folder (``images.npy`` + ``frames.csv``) or the data root the manifest's
        ``path`` column is relative to.

    Returns
    -------
    Verification

    Raises
    ------
    ManifestError
        When ``target`` does not exist, or is a folder but the manifest lists no source files
        (a rendered world dataset can only be checked against a dataset folder).
    """
    target = Path(target)
    if not target.exists():
        raise ManifestError(f"{target}: no such dataset or folder")
    if not target.is_dir():
        raise ManifestError(f"{target}: not a folder (expected a dataset folder or a data root)")
    from cmal_lcd.data.store import FRAMES_FILE, IMAGES_FILE

    if (target / IMAGES_FILE).is_file() and (target / FRAMES_FILE).is_file():
        return _verify_dataset(manifest, target)
    return _verify_folder(manifest, target)


def _label(row) -> str:
    where = row.path or f"{row.drive or row.condition} #{row.index}"
    return f"frame {row.frame} ({row.split}, {where})"


def _verify_dataset(manifest: pd.DataFrame, folder: Path) -> Verification:
    from cmal_lcd.data.store import FRAMES_FILE, IMAGES_FILE, read_frames

    try:
        images = np.load(folder / IMAGES_FILE, mmap_mode="r")
        frames = read_frames(folder / FRAMES_FILE)
    except (OSError, ValueError) as exc:
        raise ManifestError(f"{folder}: cannot read the dataset ({exc})") from None
    used = manifest[manifest["split"] != "unused"]
    result = Verification(checked=len(used))
    n = min(len(images), len(frames))
    for row in used.itertuples(index=False):
        i = int(row.frame)
        if not 0 <= i < n:
            result.missing.append(_label(row))
            continue
        stored = frames.iloc[i]
        labels_differ = (stored["split"], stored["drive"], stored["condition"]) != \
            (row.split, row.drive, row.condition)
        if labels_differ or pixels_sha256(images[i]) != row.pixels_sha256:
            result.changed.append(_label(row))
    listed = set(used["frame"].astype(int))
    result.extra = [f"frame {i} ({frames['split'].iloc[i]})" for i in range(n) if i not in listed]
    return result


def _verify_folder(manifest: pd.DataFrame, root: Path) -> Verification:
    from cmal_lcd.data.frames import IMAGE_EXTENSIONS

    if (manifest["path"] == "").all():
        raise ManifestError(f"{root}: the manifest lists no source files (a rendered world "
                            f"dataset): verify it against a dataset folder (data/dataset)")
    _check_paths_inside(manifest["path"], root)
    used = manifest[manifest["split"] != "unused"]
    result = Verification(checked=len(used))
    for row in manifest.itertuples(index=False):
        file = root / row.path
        if not file.is_file():
            result.missing.append(_label(row) if row.split != "unused" else
                                  f"{row.path} (unused)")
        elif row.split != "unused" and sha256_bytes(file.read_bytes()) != row.file_sha256:
            result.changed.append(_label(row))
    listed = set(manifest["path"])
    for sub in sorted({str(Path(p).parent) for p in listed}):
        folder = root / sub
        if not folder.is_dir():
            continue
        for file in sorted(folder.iterdir()):
            if file.suffix.lower() in IMAGE_EXTENSIONS and not file.name.startswith("."):
                path = _relative(file, root)
                if path not in listed:
                    result.extra.append(path)
    return result


def _check_paths_inside(paths: pd.Series, root: Path) -> None:
    """Refuse a ``path`` that is absolute or climbs out of ``root`` (``..``), before any file
    is read: a manifest names files of its data root only (issue 38 item 8)."""
    for row, path in enumerate(paths):
        parts = Path(path).parts
        if Path(path).is_absolute() or ".." in parts:
            raise ManifestError(f"{root}: manifest row {row} has path {path!r}, outside the "
                                f"data root (paths are relative to it, without '..'); "
                                f"nothing was read")


def _relative(file: str | os.PathLike, root: Path | None) -> str:
    """``file`` relative to ``root`` in POSIX form."""
    return Path(os.path.relpath(Path(file).resolve(), Path(root).resolve())).as_posix()


def data_root(*folders: Path) -> Path:
    """The common parent of the configured data folders (what manifest paths are relative to)."""
    return Path(os.path.commonpath([str(Path(f).resolve()) for f in folders]))
