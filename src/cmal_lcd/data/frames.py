"""Read a user's folder of frames (and optional poses) for matching.

A frame folder holds ``*.png``, ``*.jpg`` or ``*.jpeg`` files (extension case-insensitive),
taken in the order of their sorted file names (by integer value when every name is an integer,
as VPR-Bench's ``ref/`` and ``query/``; by timestamp for VPR-datasets-downloader names:
:func:`frame_order`), and optionally a ``poses.csv``.

Conversions: every image becomes ``uint8`` RGB. Grey images are repeated over the 3 channels;
an alpha channel is dropped; 16-bit images are scaled to 8 bits by ``round(v * 255 / 65535)``.

``poses.csv`` columns: ``name, x, y`` (optionally ``heading, time``), or ``frame`` instead of
``name``. A ``name``/``frame`` value is matched against the file name or its stem
(``img-001.png`` or ``img-001``); a ``frame`` column of integers that are not names gives the
0-based position in the sorted order. Every frame needs exactly one row, ``x`` and ``y`` must be
finite; rows for files that are not in the folder are an error.

Every problem raises :class:`FrameReadError` (a ``ValueError``) naming the file and the problem:
missing or empty folder, zero-byte, truncated or corrupt image, not an image, unreadable
(permissions), mixed image sizes (naming the first file whose size differs and both sizes),
bad ``poses.csv``.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import re
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import pandas as pd

logger = logging.getLogger(__name__)

#: Image file extensions read (lower case; matched case-insensitively).
IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg")
POSES_FILE = "poses.csv"

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_PNG_END = b"IEND\xaeB`\x82"
_TAIL_BYTES = 4096  # the end marker must be this close to the end (trailing data is tolerated)


def usable_cores() -> int:
    """Cores this process may run on (its CPU affinity where the OS tells it, else all): the
    threads that decode frames (``cmal-lcd match``) and render the weather world."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


class FrameReadError(ValueError):
    """A frame folder, one of its images or its ``poses.csv`` cannot be used."""


@dataclasses.dataclass(frozen=True)
class FrameFolder:
    """The frames of one folder, in sorted file-name order.

    Attributes
    ----------
    images : numpy.ndarray
        ``uint8 (N, H, W, 3)`` RGB.
    names : list of str
        File names (no directory), ``N`` of them.
    poses : pandas.DataFrame or None
        One row per frame in the same order: ``name, x, y`` and ``heading, time`` when given;
        ``None`` when the folder has no ``poses.csv``.
    sequences : numpy.ndarray or None
        ``int64 (N,)`` sequence number of every frame when the folder holds several sequences
        (a Mapillary SLS side, :mod:`cmal_lcd.data.msls`); ``None``: one sequence.
    """

    images: np.ndarray
    names: list[str]
    poses: pd.DataFrame | None = None
    sequences: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.names)

    @property
    def order(self) -> str:
        """How the frames are ordered, in words (:func:`frame_order`)."""
        if self.sequences is not None:
            from cmal_lcd.data.msls import ORDER_MSLS

            return f"{ORDER_MSLS} ({int(self.sequences.max()) + 1} sequences)"
        return frame_order(self.names)


def folder_sequences(path: str | os.PathLike) -> np.ndarray | None:
    """``int64 (N,)`` sequence numbers of a Mapillary SLS side's frames, else None."""
    from cmal_lcd.data.msls import is_msls_side, read_msls_side

    return read_msls_side(path).sequences if is_msls_side(path) else None


def list_frame_files(path: str | os.PathLike) -> list[Path]:
    """The image files of a frame folder, in frame order (:func:`frame_order`); for a
    Mapillary SLS side, ``images/<key>.jpg`` in ``seq_info.csv`` row order.

    Raises
    ------
    FrameReadError
        When ``path`` does not exist, is not a folder, or holds no image file.
    """
    from cmal_lcd.data.msls import is_msls_side, read_msls_side

    folder = Path(path)
    if not folder.exists():
        raise FrameReadError(f"{folder}: no such frame folder")
    if not folder.is_dir():
        raise FrameReadError(f"{folder}: not a folder")
    if is_msls_side(folder):
        return read_msls_side(folder).files
    files = [p for p in folder.iterdir()
             if p.suffix.lower() in IMAGE_EXTENSIONS and not p.name.startswith(".")]
    if not files:
        hint = ("; it has images/: a Mapillary SLS side also needs its seq_info.csv"
                if (folder / "images").is_dir() else "")
        raise FrameReadError(f"{folder}: no image files ({', '.join(IMAGE_EXTENSIONS)}) in the "
                             f"folder{hint}")
    return sorted(files, key=frame_order_key(files))


def frame_order_key(files: list[Path]):
    """The sort key of a folder's frames (:func:`frame_order` says which in words)."""
    order = frame_order([p.name for p in files])
    if order == ORDER_INTEGER:
        return lambda p: (int(p.stem), p.name)
    if order == ORDER_TIMESTAMP:
        return lambda p: (_name_fields(p.name)[13], p.name)
    return lambda p: p.name


#: The orders of :func:`frame_order`.
ORDER_INTEGER = "integer file names, by value"
ORDER_TIMESTAMP = "VPR-datasets-downloader names, by their timestamp field"
ORDER_NAME = "file names, sorted"


def frame_order(names: list[str]) -> str:
    """How a folder's frames are ordered, from their file names:

    - every stem an integer (VPR-Bench's layout): by value, ``2.jpg`` before ``10.jpg``
      (VPR-Bench's ``evaluate_vpr_techniques.py`` sorts with ``int(x.split(".")[0])``);
      zero-padded names sort the same either way;
    - every name a VPR-datasets-downloader name with a timestamp
      (``@east@north@zone@letter@lat@lon@pano@tile@heading@pitch@roll@height@YYYYMMDD_hhmmss@
      note@.jpg``, its ``util.py``: ``get_dst_image_name``): by the timestamp, the order in
      time (sorted by name they would be ordered by UTM east, which a sequence matcher cannot
      use);
    - else by file name.
    """
    if names and all(Path(n).stem.isascii() and Path(n).stem.isdigit() for n in names):
        return ORDER_INTEGER
    if names and all(_name_fields(n) is not None and _name_fields(n)[13] for n in names):
        return ORDER_TIMESTAMP
    return ORDER_NAME


def utm_of_names(names: list[str], *, folder: str | os.PathLike) -> np.ndarray:
    """``float64 (N, 2)`` UTM east and north of VPR-datasets-downloader file names (fields 1
    and 2 of ``name.split("@")``, as VPR-methods-evaluation's ``test_dataset.py`` reads them).

    Raises
    ------
    FrameReadError
        Naming the first file whose name carries no such coordinates.
    """
    out = np.empty((len(names), 2), dtype=np.float64)
    for i, name in enumerate(names):
        fields = name.split("@")
        try:
            out[i] = float(fields[1]), float(fields[2])
        except (IndexError, ValueError):
            out[i] = np.nan
        if not np.isfinite(out[i]).all():
            raise FrameReadError(f"{Path(folder) / name}: no UTM coordinates in the file name "
                                 f"(expected @UTM_east@UTM_north@...@.jpg, the "
                                 f"VPR-datasets-downloader layout)")
    return out


_TIMESTAMP = re.compile(r"^(\d{4}(\d{2}(\d{2}(_(\d{2})(\d{2})?(\d{2})?)?)?)?)?$")


def _name_fields(name: str) -> list[str] | None:
    """The 15 ``@`` fields of a VPR-datasets-downloader name (field 13: the timestamp), or
    None when ``name`` is not one (too few fields, or an invalid timestamp)."""
    fields = name.split("@")
    if len(fields) < 15 or fields[0] or not _TIMESTAMP.match(fields[13]):
        return None
    return fields


def read_frame_folder(path: str | os.PathLike) -> FrameFolder:
    """Read every frame of a folder (and its ``poses.csv`` when present).

    Parameters
    ----------
    path : str or os.PathLike
        The folder.

    Returns
    -------
    FrameFolder
        ``images uint8 (N, H, W, 3)``, ``names``, ``poses`` (or ``None``).

    Raises
    ------
    FrameReadError
        Naming the folder or file and the problem (see the module docs).
    """
    files = list_frame_files(path)
    first = read_image(files[0])
    images = np.empty((len(files),) + first.shape, dtype=np.uint8)
    images[0] = first
    for i, file in enumerate(files[1:], start=1):
        image = read_image(file)
        if image.shape != first.shape:
            raise FrameReadError(
                f"{file}: image size {image.shape[1]}x{image.shape[0]} (width x height) differs "
                f"from {first.shape[1]}x{first.shape[0]} of {files[0].name}; all frames of a "
                f"folder must have the same size")
        images[i] = image
    names = [f.name for f in files]
    poses_path = Path(path) / POSES_FILE
    poses = read_poses(poses_path, names) if poses_path.exists() else None
    logger.info("read %d frames of %dx%d from %s%s", len(names), first.shape[1], first.shape[0],
                path, " with poses" if poses is not None else "")
    return FrameFolder(images=images, names=names, poses=poses,
                       sequences=folder_sequences(path))


def read_image(path: str | os.PathLike) -> np.ndarray:
    """Read one image file as ``uint8 (H, W, 3)`` RGB.

    Raises
    ------
    FrameReadError
        For a missing, unreadable, zero-byte, truncated or corrupt file, or one that is not an
        image.
    """
    import cv2

    from cmal_lcd.io import NotRegularFileError, check_regular_file

    try:
        check_regular_file(path, what="a frame")
    except NotRegularFileError as exc:
        raise FrameReadError(str(exc)) from None
    try:
        # One unbuffered read: the decoder needs the whole file, the checks its two ends, and
        # pathlib's read_bytes doubles the per-file cost, which the decode threads pay under
        # the GIL (benchmarks/README.md, `cmal-lcd match`).
        with open(path, "rb", buffering=0) as file:
            data = file.readall()
    except FileNotFoundError:
        raise FrameReadError(f"{path}: no such file") from None
    except PermissionError:
        raise FrameReadError(f"{path}: cannot read the file (permission denied)") from None
    except OSError as exc:
        raise FrameReadError(f"{path}: cannot read the file ({exc.strerror or exc})") from None
    if not data:
        raise FrameReadError(f"{path}: empty (zero-byte) file")
    _check_complete(path, data)
    image = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    if image is None or image.size == 0:
        raise FrameReadError(f"{path}: not a readable image (corrupt or unsupported format)")
    return _to_rgb8(image, path=path)


def _check_complete(path: str | os.PathLike, data: bytes) -> None:
    """Reject truncated PNG/JPEG files, which decoders may silently fill with grey."""
    # Trailing NUL padding is tolerated; strip it only when there is some (a copy of the file).
    tail = (data.rstrip(b"\x00") if data.endswith(b"\x00") else data)[-_TAIL_BYTES:]
    if data.startswith(_PNG_SIGNATURE):
        if _PNG_END not in tail:
            raise FrameReadError(f"{path}: truncated or corrupt PNG (no IEND chunk at the end)")
    elif data.startswith(b"\xff\xd8"):
        if b"\xff\xd9" not in tail:
            raise FrameReadError(f"{path}: truncated or corrupt JPEG (no end-of-image marker)")
    else:
        raise FrameReadError(f"{path}: not a PNG or JPEG image (unrecognised file header)")


def _to_rgb8(image: np.ndarray, *, path: str | os.PathLike) -> np.ndarray:
    """OpenCV's BGR(A)/grey, 8- or 16-bit -> ``uint8 (H, W, 3)`` RGB."""
    if image.dtype == np.uint16:
        image = ((image.astype(np.uint32) * 255 + 32767) // 65535).astype(np.uint8)
    elif image.dtype != np.uint8:
        raise FrameReadError(f"{path}: unsupported pixel type {image.dtype} (expected 8 or "
                             f"16 bits)")
    if image.ndim == 2:
        return np.repeat(image[:, :, None], 3, axis=2)
    if image.ndim == 3 and image.shape[2] == 1:
        return np.repeat(image, 3, axis=2)
    if image.ndim == 3 and image.shape[2] in (3, 4):
        return np.ascontiguousarray(image[:, :, 2::-1])
    raise FrameReadError(f"{path}: unsupported image layout {image.shape}")


def read_poses(path: str | os.PathLike, names: list[str]) -> pd.DataFrame:
    """Read and validate ``poses.csv`` for the frames ``names`` (sorted file names).

    Returns
    -------
    pandas.DataFrame
        One row per name, in that order: ``name, x, y`` (+ ``heading, time`` when present).

    Raises
    ------
    FrameReadError
        When the file cannot be parsed, lacks columns, has NaN or non-numeric ``x``/``y``,
        duplicate or unknown frames, or misses a frame.
    """
    path = Path(path)
    table, key = _read_pose_table(path)
    rows = _pose_rows(table[key].tolist(), names, path=path)
    return _aligned_poses(table, rows, names, path=path)


def _read_pose_table(path: Path) -> tuple[pd.DataFrame, str]:
    """``(table, key)``: the parsed CSV with stripped lower-case column names, and its frame
    column (``name``, else ``frame``); refuses a file without it or ``x``, ``y``."""
    import pandas as pd  # here, not at the top: reading frames without poses needs no pandas

    from cmal_lcd.io import NotRegularFileError, check_regular_file

    try:
        check_regular_file(path, what="poses.csv")
        table = pd.read_csv(path, skipinitialspace=True)
    except NotRegularFileError as exc:
        raise FrameReadError(str(exc)) from None
    except (OSError, ValueError, pd.errors.ParserError) as exc:
        raise FrameReadError(f"{path}: cannot parse the CSV file ({exc})") from None
    table.columns = [str(c).strip().lower() for c in table.columns]
    key = "name" if "name" in table.columns else "frame" if "frame" in table.columns else None
    missing = [c for c in ("x", "y") if c not in table.columns]
    if key is None or missing:
        raise FrameReadError(f"{path}: needs columns name (or frame), x, y; has "
                             f"{list(table.columns)}")
    return table, key


def _pose_rows(values: list, names: list[str], *, path: Path) -> list[int]:
    """Position in ``names`` of each row's frame cell; refuses unknown frames, a frame on two
    rows, and frames without a row."""
    by_name = {n: i for i, n in enumerate(names)}
    by_stem = {Path(n).stem: i for i, n in enumerate(names)}
    rows = [_resolve_frame(value, by_name, by_stem, len(names), path=path, line=i + 2)
            for i, value in enumerate(values)]
    seen: dict[int, int] = {}
    for i, row in enumerate(rows):
        if row in seen:
            raise FrameReadError(f"{path}: line {i + 2}: duplicate row for frame {names[row]} "
                                 f"(first on line {seen[row] + 2})")
        seen[row] = i
    absent = [n for j, n in enumerate(names) if j not in seen]
    if absent:
        raise FrameReadError(f"{path}: no pose for {len(absent)} frame(s), first {absent[0]}")
    return rows


def _aligned_poses(table: pd.DataFrame, rows: list[int], names: list[str], *,
                   path: Path) -> pd.DataFrame:
    """``name, x, y`` (+ ``heading, time``) float64 in ``names`` order (row ``i`` of ``table``
    is frame ``rows[i]``); refuses a missing or non-finite ``x`` or ``y``."""
    import pandas as pd

    columns = ["x", "y"] + [c for c in ("heading", "time") if c in table.columns]
    out = pd.DataFrame({"name": names})
    order = np.empty(len(names), dtype=np.int64)
    order[rows] = np.arange(len(rows))
    for column in columns:
        values = pd.to_numeric(table[column], errors="coerce").to_numpy(dtype=np.float64)
        bad = ~np.isfinite(values) if column in ("x", "y") else np.zeros(len(values), bool)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise FrameReadError(f"{path}: line {i + 2}: {column} is missing or not a finite "
                                 f"number ({table[column].iloc[i]!r})")
        out[column] = values[order]
    return out


def _resolve_frame(value, by_name: dict[str, int], by_stem: dict[str, int], n_frames: int, *,
                   path: Path, line: int) -> int:
    """Position of a ``name``/``frame`` cell: file name, stem, or 0-based index."""
    text = str(value).strip()
    if text in by_name:
        return by_name[text]
    if text in by_stem:
        return by_stem[text]
    if isinstance(value, (int, np.integer)) and not isinstance(value, bool):
        if 0 <= int(value) < n_frames:
            return int(value)
    raise FrameReadError(f"{path}: line {line}: frame {text!r} is not an image of the folder")
