"""The two sides of a user's pair: two frame folders or two descriptor files, checked.

``cmal-lcd match`` reads either two folders of frames
(:class:`~cmal_lcd.data.frames.FrameFolder`) or two files of precomputed descriptors
(:class:`DescriptorFile`, rows = frames; :mod:`cmal_lcd.data.descriptors`). This module says
which (:func:`input_features`), reads both (:func:`read_inputs`) and refuses pairs the search
cannot use (:func:`check_lengths`, :func:`check_poses_in_both`), each refusal one
``ValueError`` naming the file, folder or option.
"""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # imported lazily at run time
    import numpy as np

logger = logging.getLogger(__name__)

#: The ``features`` of descriptor files (:mod:`cmal_lcd.data.descriptors`): matched as given,
#: by squared Euclidean distance (eq. 13).
PRECOMPUTED = "precomputed"


@dataclasses.dataclass(frozen=True)
class DescriptorFile:
    """The descriptors of one side, read from a file: ``descriptors (N, D)``, rows = frames."""

    descriptors: np.ndarray
    path: Path
    key: str | None = None
    poses = None  # descriptor files carry no poses
    sequences = None  # and hold one sequence

    def __len__(self) -> int:
        return len(self.descriptors)

    @property
    def names(self) -> list[str]:
        return [str(i) for i in range(len(self))]


def input_features(reference, query, features: str | None, *,
                    descriptor_key: str | None) -> str:
    """The ``features`` to match with: :data:`PRECOMPUTED` for two descriptor files, else
    ``features`` (default ``sad``). Refuses one file and one folder, ``--features`` with
    files, ``--descriptor-key`` with folders."""
    from cmal_lcd.data.array_files import ARRAY_SUFFIXES, is_array_file

    files = [is_array_file(reference), is_array_file(query)]
    if files[0] != files[1]:
        file, folder = (reference, query) if files[0] else (query, reference)
        raise ValueError(f"{folder}: a folder of frames, but {file} is a descriptor file; "
                         f"give two descriptor files ({', '.join(ARRAY_SUFFIXES)}) or two "
                         f"folders")
    if files[0]:
        if features not in (None, PRECOMPUTED):
            raise ValueError(f"--features {features}: descriptor files are matched as given; "
                             f"leave --features out")
        return PRECOMPUTED
    if descriptor_key is not None:
        raise ValueError(f"--descriptor-key {descriptor_key}: only with descriptor files, but "
                         f"{reference} and {query} are folders of frames")
    return "sad" if features is None else features


def read_inputs(reference, query, *, workers: int | None, descriptor_key: str | None,
                descriptors: bool):
    """Both sides: :class:`DescriptorFile` when ``descriptors`` (same dimensions checked),
    else :class:`~cmal_lcd.data.frames.FrameFolder` (read on ``workers`` threads)."""
    if not descriptors:
        from cmal_lcd.data.frames import read_frame_folder

        return (read_frame_folder(reference, workers=workers),
                read_frame_folder(query, workers=workers))
    from cmal_lcd.data.descriptors import read_descriptors

    sides = [DescriptorFile(read_descriptors(path, key=descriptor_key), Path(path),
                            descriptor_key) for path in (reference, query)]
    dims = [side.descriptors.shape[1] for side in sides]
    if dims[0] != dims[1]:
        raise ValueError(f"{query}: descriptors of {dims[1]} dimensions, but {reference} has "
                         f"{dims[0]}")
    for side in sides:
        logger.info("read %d descriptors of %d dimensions from %s", len(side), dims[0],
                    side.path)
    return sides[0], sides[1]


def check_lengths(reference_dir, n_reference: int, query_dir, n_query: int, *, ds: int) -> None:
    """Refuse folders too short for the look-back search (naming the folder and ``ds``)."""
    if n_query <= ds:
        raise ValueError(f"{query_dir}: {n_query} query frames; the look-back search needs "
                         f"more than ds={ds}")
    if n_reference < ds:
        raise ValueError(f"{reference_dir}: {n_reference} reference frames; a sequence "
                         f"spans ds={ds} frames of the reference, so it needs at least "
                         f"ds frames")


def check_poses_in_both(reference_dir, reference_has_poses: bool, query_dir,
                        query_has_poses: bool) -> None:
    """Refuse ``poses.csv`` in only one folder (it would silently fall back to index truth).

    Raises
    ------
    ValueError
        ``<folder without poses>: no poses.csv, but <other>/poses.csv exists; ...``.
    """
    if reference_has_poses == query_has_poses:
        return
    missing, other = ((query_dir, reference_dir) if reference_has_poses
                      else (reference_dir, query_dir))
    raise ValueError(f"{missing}: no poses.csv, but {Path(other) / 'poses.csv'} exists; give "
                     f"both folders poses.csv (ground truth from poses) or neither (query frame "
                     f"i is reference frame i)")
