"""Mapillary SLS (MSLS) sides: ``<city>/query/`` and ``<city>/database/``, read as its code does.

Layout (github: mapillary/mapillary_sls, README and ``mapillary_sls/datasets/msls.py``)::

    <city>/database/images/<key>.jpg
    <city>/database/seq_info.csv       index, key, sequence_key, frame_number
    <city>/database/postprocessed.csv  index, key, ..., easting, northing, ..., night, ...

- **Frame order**: the rows of ``seq_info.csv``. ``msls.py`` (``arange_as_seq``) walks them in
  file order and keeps a window only when its rows share one ``sequence_key`` and have
  consecutive ``frame_number`` s, so the row order is the travel order; the keys are random
  strings, so the images' name order is not.
- **Sequences**: a side holds many short drives. A sequence here is a run of rows with one
  ``sequence_key`` and consecutive ``frame_number`` s (the windows ``arange_as_seq`` accepts);
  sequence matching never crosses from one to the next
  (:class:`cmal_lcd.matching.SequenceBlocks`).
- **Positions**: ``easting`` and ``northing`` of ``postprocessed.csv``, whose rows are the rows
  of ``seq_info.csv`` (``msls.py`` indexes one by the other's positions); the keys are checked
  to agree row by row.

Every problem raises :class:`~cmal_lcd.data.frames.FrameReadError` naming the file.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import numpy as np

SEQ_INFO = "seq_info.csv"
POSITIONS = "postprocessed.csv"
IMAGES = "images"
SEQ_COLUMNS = ("key", "sequence_key", "frame_number")
POSITION_COLUMNS = ("key", "easting", "northing")
#: How :attr:`cmal_lcd.data.frames.FrameFolder.order` words this order.
ORDER_MSLS = "Mapillary SLS seq_info.csv row order"


def is_msls_side(path: str | os.PathLike) -> bool:
    """Whether ``path`` is an MSLS side: a folder holding ``seq_info.csv`` and ``images/``."""
    folder = Path(path)
    return (folder / SEQ_INFO).is_file() and (folder / IMAGES).is_dir()


@dataclasses.dataclass(frozen=True)
class MslsSide:
    """One side of an MSLS city.

    Attributes
    ----------
    files : list of Path
        ``images/<key>.jpg`` in ``seq_info.csv`` row order, ``N`` of them.
    sequences : numpy.ndarray
        ``int64 (N,)`` sequence number of every frame, ``0, 0, ..., 1, ...`` (runs of one
        ``sequence_key`` with consecutive ``frame_number`` s).
    """

    files: list[Path]
    sequences: np.ndarray

    @property
    def n_sequences(self) -> int:
        return int(self.sequences[-1]) + 1 if len(self.sequences) else 0


def read_msls_side(path: str | os.PathLike) -> MslsSide:
    """The frames and sequences of an MSLS side (see the module docs).

    Raises
    ------
    FrameReadError
        ``seq_info.csv`` unreadable, without its columns or empty; a key without its image.
    """
    folder = Path(path)
    table = _read_table(folder / SEQ_INFO, SEQ_COLUMNS)
    files = [folder / IMAGES / f"{key}.jpg" for key in table["key"].astype(str)]
    missing = next((file for file in files if not file.is_file()), None)
    if missing is not None:
        from cmal_lcd.data.frames import FrameReadError

        raise FrameReadError(f"{missing}: no such image, but {folder / SEQ_INFO} lists key "
                             f"{missing.stem!r}")
    return MslsSide(files=files, sequences=_sequence_numbers(table, folder / SEQ_INFO))


def msls_positions(path: str | os.PathLike) -> np.ndarray:
    """``float64 (N, 2)`` easting and northing of every frame, in ``seq_info.csv`` row order.

    Raises
    ------
    FrameReadError
        No or unreadable ``postprocessed.csv``, a missing column, a non-finite coordinate, or
        keys that differ from ``seq_info.csv`` 's row by row.
    """
    import pandas as pd

    from cmal_lcd.data.frames import FrameReadError

    folder = Path(path)
    order = _read_table(folder / SEQ_INFO, SEQ_COLUMNS)["key"].astype(str).to_numpy()
    table = _read_table(folder / POSITIONS, POSITION_COLUMNS)
    keys = table["key"].astype(str).to_numpy()
    if len(keys) != len(order) or (keys != order).any():
        row = (min(len(keys), len(order)) if len(keys) != len(order)
               else int(np.flatnonzero(keys != order)[0]))
        raise FrameReadError(f"{folder / POSITIONS}: its keys differ from {SEQ_INFO}'s at row "
                             f"{row} ({len(keys)} rows against {len(order)}); MSLS reads the "
                             f"two files row by row")
    xy = table[["easting", "northing"]].apply(pd.to_numeric, errors="coerce").to_numpy(float)
    bad = np.flatnonzero(~np.isfinite(xy).all(axis=1))
    if bad.size:
        raise FrameReadError(f"{folder / POSITIONS}: row {int(bad[0])} (key {keys[bad[0]]!r}) "
                             f"has no finite easting/northing")
    return xy


def _read_table(path: Path, columns: tuple[str, ...]):
    """``path`` read as MSLS does (``pd.read_csv(..., index_col=0)``), checked for ``columns``:
    a ``pandas.DataFrame`` (pandas is imported here, so that SAD matching of plain folders
    never loads it)."""
    import pandas as pd

    from cmal_lcd.data.frames import FrameReadError

    if not path.is_file():
        raise FrameReadError(f"{path}: no such file (an MSLS side needs {SEQ_INFO} and, for "
                             f"its ground truth, {POSITIONS})")
    from cmal_lcd.io import NotRegularFileError, check_regular_file

    try:
        check_regular_file(path, what=path.name)
        table = pd.read_csv(path, index_col=0)
    except NotRegularFileError as exc:
        raise FrameReadError(str(exc)) from None
    except (OSError, ValueError, pd.errors.ParserError) as err:
        raise FrameReadError(f"{path}: not a readable CSV ({err})") from None
    missing = [c for c in columns if c not in table.columns]
    if missing:
        raise FrameReadError(f"{path}: no column {', '.join(missing)} (MSLS's {path.name} has "
                             f"{', '.join(columns)})")
    if table.empty:
        raise FrameReadError(f"{path}: no rows")
    return table


def _sequence_numbers(table, path: Path) -> np.ndarray:
    """``int64 (N,)``: a new number where ``sequence_key`` changes or ``frame_number`` does not
    go up by exactly 1 (``arange_as_seq`` 's test for a window)."""
    import pandas as pd

    from cmal_lcd.data.frames import FrameReadError

    frame = pd.to_numeric(table["frame_number"], errors="coerce").to_numpy(float)
    if not np.isfinite(frame).all():
        row = int(np.flatnonzero(~np.isfinite(frame))[0])
        raise FrameReadError(f"{path}: row {row} has no frame_number")
    key = table["sequence_key"].astype(str).to_numpy()
    new = np.ones(len(key), dtype=bool)
    new[1:] = (key[1:] != key[:-1]) | (np.diff(frame) != 1)
    return (np.cumsum(new) - 1).astype(np.int64)
