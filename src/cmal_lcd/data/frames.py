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
bad ``poses.csv``; a frame, or a folder of frames, too large for the memory available (read
from the image header, before anything is decoded or allocated).
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import os
import re
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from cmal_lcd.kernels import usable_cores

if TYPE_CHECKING:
    import pandas as pd

logger = logging.getLogger(__name__)

#: Image file extensions read (lower case; matched case-insensitively).
IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg")
POSES_FILE = "poses.csv"

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_PNG_END = b"IEND\xaeB`\x82"
_TAIL_BYTES = 4096  # the end marker must be this close to the end (trailing data is tolerated)


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


def read_frame_folder(path: str | os.PathLike, *, workers: int | None = None) -> FrameFolder:
    """Read every frame of a folder (and its ``poses.csv`` when present).

    The frames are decoded on ``workers`` threads, each decoding a contiguous run of files
    straight into the array (``cv2`` decodes without the GIL); the result and the error (the
    first bad file in name order) are those of reading one file after the other.

    Parameters
    ----------
    path : str or os.PathLike
        The folder.
    workers : int, optional
        Decoding threads (default: the usable cores, at most 8).

    Returns
    -------
    FrameFolder
        ``images uint8 (N, H, W, 3)``, ``names``, ``poses`` (or ``None``).

    Raises
    ------
    FrameReadError
        Naming the folder or file and the problem (see the module docs).
    """
    from concurrent.futures import ThreadPoolExecutor

    files = list_frame_files(path)
    first = read_image(files[0])
    check_fits_in_memory((len(files),) + first.shape,
                         what=f"{path}: {len(files)} frames of {first.shape[1]}x"
                              f"{first.shape[0]} (as {files[0].name})")
    images = np.empty((len(files),) + first.shape, dtype=np.uint8)
    images[0] = first
    workers = min(8, usable_cores()) if workers is None else max(1, workers)
    runs = [run for run in np.array_split(np.arange(1, len(files)), workers) if len(run)]
    with ThreadPoolExecutor(max_workers=max(1, len(runs))) as pool:
        failures = [f for f in pool.map(lambda run: _decode_run(files, run, images), runs) if f]
    if failures:
        raise min(failures, key=lambda failure: failure[0])[1]
    names = [f.name for f in files]
    poses_path = Path(path) / POSES_FILE
    poses = read_poses(poses_path, names) if poses_path.exists() else None
    logger.info("read %d frames of %dx%d from %s%s", len(names), first.shape[1], first.shape[0],
                path, " with poses" if poses is not None else "")
    return FrameFolder(images=images, names=names, poses=poses,
                       sequences=folder_sequences(path))


def _decode_run(files: list[Path], rows, images: np.ndarray):
    """Decode ``files[rows]`` into ``images[rows]`` (``uint8 (N, H, W, 3)``, row 0 read);
    ``(row, FrameReadError)`` of the first bad file, else None."""
    for i in rows:
        try:
            images[i] = read_image(files[i], size=images.shape[1:3], like=files[0].name)
        except FrameReadError as err:
            return i, err
    return None


def read_image(path: str | os.PathLike, *, size: tuple[int, int] | None = None,
               like: str | None = None) -> np.ndarray:
    """Read one image file as ``uint8 (H, W, 3)`` RGB.

    Parameters
    ----------
    path : str or os.PathLike
    size : (int, int), optional
        The ``(H, W)`` every frame must have; a file of another size (from its header when
        it has one, before decoding) is refused, naming ``like``, the frame that set it.
    like : str, optional

    Raises
    ------
    FrameReadError
        For a missing, unreadable, zero-byte, truncated or corrupt file, one that is not an
        image, one of another size than ``size``, or one whose decoded pixels (from its header)
        would not fit in the memory available.
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
    header = header_size(data)
    if header is not None:
        if size is not None:
            _check_same_size(path, header, size, like)
        # OpenCV decodes up to 4 channels of 16 bits, then the RGB copy
        check_fits_in_memory((header[0], header[1], 4 * 2 + 3),
                             what=f"{path}: an image of {header[1]}x{header[0]}")
    _quiet_opencv()
    image = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    if image is None or image.size == 0:
        raise FrameReadError(f"{path}: not a readable image (corrupt or unsupported format)")
    image = _to_rgb8(image, path=path)
    if size is not None:
        _check_same_size(path, image.shape[:2], size, like)
    return image


@functools.cache
def _quiet_opencv() -> None:
    """OpenCV's own warnings (``[ WARN:0@0.25] ... PNG input buffer is incomplete``) off: a
    file it cannot decode gets the project's one line naming it instead."""
    import cv2

    logging_module = getattr(getattr(cv2, "utils", None), "logging", None)
    if logging_module is not None:
        logging_module.setLogLevel(logging_module.LOG_LEVEL_ERROR)


def _check_same_size(path, got: tuple[int, int], size: tuple[int, int], like: str | None) -> None:
    """Refuse a frame of ``got`` ``(H, W)`` in a folder of ``size`` frames."""
    if tuple(got) != tuple(size):
        raise FrameReadError(
            f"{path}: image size {got[1]}x{got[0]} (width x height) differs from "
            f"{size[1]}x{size[0]} of {like}; all frames of a folder must have the same size")


def header_size(data: bytes) -> tuple[int, int] | None:
    """``(H, W)`` from a PNG's IHDR chunk or a JPEG's start-of-frame marker; None when the
    header does not say (the decoder then finds out)."""
    if data.startswith(_PNG_SIGNATURE) and data[12:16] == b"IHDR" and len(data) >= 24:
        return int.from_bytes(data[20:24], "big"), int.from_bytes(data[16:20], "big")
    if not data.startswith(b"\xff\xd8"):
        return None
    at = 2
    while at + 9 <= len(data):
        if data[at] != 0xFF:
            return None
        marker = data[at + 1]
        if marker in (0xD8, 0x01) or 0xD0 <= marker <= 0xD7 or marker == 0xFF:
            at += 1 if marker == 0xFF else 2
            continue
        length = int.from_bytes(data[at + 2:at + 4], "big")
        if 0xC0 <= marker <= 0xCF and marker not in (0xC4, 0xC8, 0xCC):
            return (int.from_bytes(data[at + 5:at + 7], "big"),
                    int.from_bytes(data[at + 7:at + 9], "big"))
        if marker == 0xDA or length < 2:  # image data before any frame header
            return None
        at += 2 + length
    return None


def available_memory() -> int:
    """Bytes of memory this process can still take: ``MemAvailable`` of ``/proc/meminfo``,
    else the free physical pages."""
    try:
        with open("/proc/meminfo", encoding="ascii") as file:
            for line in file:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):  # pragma: no cover - not POSIX
        return 1 << 62


def check_fits_in_memory(shape: tuple[int, ...], *, what: str) -> None:
    """Refuse to allocate ``uint8`` ``shape`` when it exceeds :func:`available_memory`.

    Raises
    ------
    FrameReadError
        ``<what>: X GiB of pixels, more than the Y GiB of memory available; ...``.
    """
    need = int(np.prod(shape, dtype=np.float64))
    have = available_memory()
    if need > have:
        raise FrameReadError(f"{what}: {_in_units(need)} of pixels, more than the "
                             f"{_in_units(have)} of memory available; resize the frames first, "
                             f"or read fewer")


def _in_units(n_bytes: int) -> str:
    """``68.2 GiB``, ``146.5 KiB``: one decimal in the largest binary unit below it."""
    for unit, scale in (("GiB", 2**30), ("MiB", 2**20), ("KiB", 2**10)):
        if n_bytes >= scale:
            return f"{n_bytes / scale:.1f} {unit}"
    return f"{n_bytes} bytes"


def _check_complete(path: str | os.PathLike, data: bytes) -> None:
    """Reject truncated PNG/JPEG files, which decoders may silently fill with grey."""
    # Trailing NUL padding is tolerated; strip it only when there is some (a copy of the file).
    tail = (data.rstrip(b"\x00") if data.endswith(b"\x00") else data)[-_TAIL_BYTES:]
    if data.startswith(_PNG_SIGNATURE):
        if _PNG_END not in tail:
            raise FrameReadError(f"{path}: truncated or corrupt PNG (no IEND chunk at the end)")
        _check_png_chunks(path, data)
    elif data.startswith(b"\xff\xd8"):
        if b"\xff\xd9" not in tail:
            raise FrameReadError(f"{path}: truncated or corrupt JPEG (no end-of-image marker)")
    else:
        raise FrameReadError(f"{path}: not a PNG or JPEG image (unrecognised file header)")


def _check_png_chunks(path: str | os.PathLike, data: bytes) -> None:
    """Reject a PNG whose chunks do not chain to IEND or fail their CRC: libpng would print
    its own ``libpng error: ...`` line before ours (issue 38)."""
    import zlib

    view = memoryview(data)
    at = len(_PNG_SIGNATURE)
    while at + 12 <= len(data):
        length = int.from_bytes(view[at:at + 4], "big")
        end = at + 8 + length
        if end + 4 > len(data):
            break
        kind = bytes(view[at + 4:at + 8])
        if zlib.crc32(view[at + 4:end]) != int.from_bytes(view[end:end + 4], "big"):
            raise FrameReadError(f"{path}: corrupt PNG (its {kind.decode('latin-1')!r} chunk "
                                 f"fails its CRC check)")
        if kind == b"IEND":
            return
        at = end + 4
    raise FrameReadError(f"{path}: truncated or corrupt PNG (its chunks do not reach IEND)")


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
