"""Ground-truth files of the field, read as their own toolkits read them.

Each reader returns a :class:`~cmal_lcd.data.ground_truth.ReferenceSets` (the right,
and the ignored, reference rows of every query) that every metric accepts in place of index
truth. The formats (``docs/ground_truth.md`` cites the toolkit files):

- **VPR-Bench** ``ground_truth_new.npy``: an object array with one row per query,
  ``[q, correct reference indices]`` (a list, a ``range`` or an array). VPR-Bench reads row
  ``q`` as query ``q`` (``performance_comparison.py``: ``ground_truth_info[query][1]``), so
  the first entry of each row must be its position.
- **VPR_Tutorial** ``GThard`` and optional ``GTsoft``: boolean (or 0/1) matrices of shape
  ``(reference, query)``, as ``.npz`` keys, MATLAB variables or the fields of a struct (``GT``
  in a ``.mat`` v5 or v7.3 file), or HDF5 datasets; a plain ``.npy`` matrix is ``GThard``.
  Entries true in ``GTsoft`` only are neither right nor wrong (``evaluation/metrics.py``,
  ``createPR``).

- **VPR-methods-evaluation** (``utm``, from the folders, no file): every frame's UTM east and
  north are fields 1 and 2 of its ``@``-separated file name (VPR-datasets-downloader's
  layout); a reference frame is right for a query within ``positive_dist_threshold`` metres
  (25 by default), found with scikit-learn's ``NearestNeighbors.radius_neighbors`` as
  ``test_dataset.py`` does.
- **Mapillary SLS** (``msls``, from the two sides' CSVs, no file): ``easting`` and
  ``northing`` of each side's ``postprocessed.csv`` (:mod:`cmal_lcd.data.msls`); right within
  ``positive_dist_threshold`` metres (25 by default, ``evaluate.py`` ``--threshold``), with
  ``radius_neighbors`` as ``mapillary_sls/datasets/msls.py`` does.

Every problem raises :class:`GroundTruthFileError` (a ``ValueError``) naming the file.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from cmal_lcd.data.array_files import ArrayFileError, read_arrays
from cmal_lcd.data.ground_truth import ReferenceSets

#: ``format`` values written to ``metrics.json``.
VPR_BENCH = "VPR-Bench ground_truth_new.npy"
GT_MATRICES = "VPR_Tutorial GThard/GTsoft"
UTM_NAMES = "VPR-methods-evaluation UTM file names"
MSLS_CSV = "Mapillary SLS postprocessed.csv easting/northing"

#: ``--ground-truth`` keyword of :func:`utm_ground_truth` (positions from the file names).
UTM = "utm"
#: ``--ground-truth`` keyword of :func:`msls_ground_truth` (positions from the sides' CSVs).
MSLS = "msls"
#: The ground truths computed from positions within a radius, by ``--ground-truth`` keyword.
POSITION_KEYWORDS = (UTM, MSLS)


class GroundTruthFileError(ValueError):
    """A ground-truth file cannot be read, or does not fit the frames it is used with."""


def default_radius() -> float:
    """The radius of both when none is given, metres: ``positive_dist_threshold`` of
    ``conf/data/folders.yaml`` (25, VPR-methods-evaluation's ``positive_dist_threshold`` in its
    ``parser.py`` and MSLS's ``evaluate.py`` ``--threshold``)."""
    from cmal_lcd.schema import group_option

    return group_option("data", "folders")["positive_dist_threshold"]


def check_radius(radius) -> float:
    """``radius`` as a float, checked by the schema's rule of ``data.positive_dist_threshold``
    (the one check of it).

    Raises
    ------
    GroundTruthFileError
        ``--positive-dist-threshold: must be > 0.0, got -1.0``.
    """
    from cmal_lcd.fields import SchemaError, check_values
    from cmal_lcd.schema import FoldersDataSchema

    try:
        return check_values(FoldersDataSchema, {"positive_dist_threshold": radius}
                            )["positive_dist_threshold"]
    except SchemaError as err:
        raise GroundTruthFileError(f"--positive-dist-threshold: {str(err).partition(': ')[2]}"
                                   ) from None


def read_ground_truth_file(path: str | os.PathLike, *, n_reference: int,
                           n_query: int, name: str | None = None) -> ReferenceSets:
    """The ground truth of ``path`` for ``n_reference`` reference and ``n_query`` query frames
    (``name``: how the source names the file; default the path).

    The format is recognised from the content: an object array of ``[q, indices]`` rows is
    VPR-Bench's; ``GThard`` (and ``GTsoft``) matrices are VPR_Tutorial's.

    Raises
    ------
    GroundTruthFileError
        Unreadable file, neither format, sizes that differ from the frames given, indices
        outside the reference.
    """
    path = Path(path)
    try:
        arrays = read_arrays(path)
    except ArrayFileError as err:
        raise GroundTruthFileError(f"ground truth {err}") from None
    try:
        if list(arrays) == [""] and arrays[""].dtype == object:
            sets = _vpr_bench(arrays[""], n_reference=n_reference, n_query=n_query, path=path,
                              label=name or str(path))
        else:
            sets = _matrices(arrays, path=path, n_reference=n_reference, n_query=n_query,
                             label=name or str(path))
    except GroundTruthFileError:
        raise
    except ValueError as err:
        raise GroundTruthFileError(f"ground truth {path}: {err}") from None
    return sets


def describe_ground_truth(sets: ReferenceSets) -> dict:
    """What ``metrics.json`` says of a file's ground truth: ``format``, ``source``,
    ``tolerance``, the counts of right and ignored pairs and of queries with no right row."""
    return {**sets.describe(),
            "n_query_without_reference": int(np.sum(~sets.has_place()))}


def utm_ground_truth(reference_names: list[str], query_names: list[str], *,
                     reference_dir: str | os.PathLike, query_dir: str | os.PathLike,
                     radius: float | None = None) -> ReferenceSets:
    """Right references within ``radius`` metres (UTM east/north from the file names; default
    :func:`default_radius`).

    Raises
    ------
    GroundTruthFileError
        ``radius`` not a positive finite number; a file name without coordinates.
    """
    from cmal_lcd.data.frames import FrameReadError, utm_of_names

    radius = check_radius(default_radius() if radius is None else radius)
    try:
        reference = utm_of_names(reference_names, folder=reference_dir)
        query = utm_of_names(query_names, folder=query_dir)
    except FrameReadError as err:
        raise GroundTruthFileError(f"--ground-truth {UTM}: {err}") from None
    return _within_radius(reference, query, radius=radius,
                          source=f"{UTM_NAMES}: {reference_dir}, {query_dir}",
                          coordinates="UTM east/north")


def msls_ground_truth(reference_dir: str | os.PathLike, query_dir: str | os.PathLike, *,
                      radius: float | None = None,
                      names: tuple[str, str] | None = None) -> ReferenceSets:
    """Right references within ``radius`` metres (default :func:`default_radius`) of Mapillary
    SLS sides (``easting`` and
    ``northing`` of their ``postprocessed.csv``, rows in ``seq_info.csv`` order); ``names``:
    how the source names the two sides (default their paths).

    Raises
    ------
    GroundTruthFileError
        ``radius`` not a positive finite number; a side that is not an MSLS side; a
        ``postprocessed.csv`` that is missing, lacks a column or disagrees with ``seq_info.csv``.
    """
    from cmal_lcd.data.frames import FrameReadError
    from cmal_lcd.data.msls import POSITIONS, SEQ_INFO, is_msls_side, msls_positions

    radius = check_radius(default_radius() if radius is None else radius)
    for folder in (reference_dir, query_dir):
        if not is_msls_side(folder):
            raise GroundTruthFileError(f"--ground-truth {MSLS}: {folder} is not a Mapillary SLS "
                                       f"side (a folder with {SEQ_INFO}, {POSITIONS} and images/)")
    try:
        reference, query = msls_positions(reference_dir), msls_positions(query_dir)
    except FrameReadError as err:
        raise GroundTruthFileError(f"--ground-truth {MSLS}: {err}") from None
    names = (str(reference_dir), str(query_dir)) if names is None else names
    return _within_radius(reference, query, radius=radius,
                          source=f"{MSLS_CSV}: {names[0]}, {names[1]}",
                          coordinates="easting/northing")


def _within_radius(reference: np.ndarray, query: np.ndarray, *, radius: float, source: str,
                   coordinates: str) -> ReferenceSets:
    """Right references: those within ``radius`` of the query, ``reference (R, 2)`` and
    ``query (Q, 2)`` in metres (``radius_neighbors``, as VPR-methods-evaluation and MSLS)."""
    from sklearn.neighbors import NearestNeighbors

    positives = NearestNeighbors().fit(reference).radius_neighbors(
        query, radius=radius, return_distance=False)
    counts = np.array([len(rows) for rows in positives])
    return ReferenceSets.from_lists(
        [np.sort(rows) for rows in positives], n_reference=len(reference), source=source,
        tolerance=f"{radius:g} m ({coordinates}; {_spread(counts)} right reference frames "
                  f"per query)")


# ---------------------------------------------------------------------------- formats


def _vpr_bench(array: np.ndarray, *, n_reference: int, n_query: int, path: Path,
               label: str) -> ReferenceSets:
    if array.ndim != 2 or array.shape[1] != 2:
        raise GroundTruthFileError(
            f"ground truth {path}: an object array of shape {array.shape}; VPR-Bench's "
            f"ground_truth_new.npy has one row [query index, reference indices] per query")
    if array.shape[0] != n_query:
        raise GroundTruthFileError(f"ground truth {path}: {array.shape[0]} query rows, but "
                                   f"there are {n_query} query frames")
    lists = []
    for q, (index, references) in enumerate(array):
        if _as_int(index) != q:
            raise GroundTruthFileError(
                f"ground truth {path}: row {q} names query {index!r}; VPR-Bench reads row q "
                f"as query q, so rows must be in query order")
        if isinstance(references, (int, np.integer)):
            references = [references]
        lists.append(np.asarray(list(references)))
    counts = np.array([len(rows) for rows in lists])
    return ReferenceSets.from_lists(
        lists, n_reference=n_reference, source=f"{VPR_BENCH}: {label}",
        tolerance=f"as listed in the file ({_spread(counts)} right reference frames per query)")


def _matrices(arrays: dict, *, path: Path, n_reference: int, n_query: int,
              label: str) -> ReferenceSets:
    if list(arrays) == [""]:
        hard_name, hard, soft = "", arrays[""], None
    else:
        hard_name = _one_name(arrays, "GThard", path=path)
        prefix = hard_name[:-len("GThard")]
        hard = arrays[hard_name]
        soft = arrays.get(prefix + "GTsoft")
    shape = tuple(hard.shape)
    if len(shape) != 2:
        raise GroundTruthFileError(f"ground truth {path}: GThard has shape {shape}; expected a "
                                   f"(reference, query) matrix")
    if shape != (n_reference, n_query):
        hint = (" (it looks transposed: VPR_Tutorial's matrices are reference x query)"
                if shape == (n_query, n_reference) else "")
        raise GroundTruthFileError(
            f"ground truth {path}: GThard is {shape[0]} x {shape[1]} (reference x query), but "
            f"there are {n_reference} reference and {n_query} query frames{hint}")
    tolerance = ("GThard as given; GTsoft-only entries ignored (neither right nor wrong)"
                 if soft is not None else "GThard as given (no GTsoft)")
    return ReferenceSets.from_matrices(hard, soft, source=f"{GT_MATRICES}: {label}",
                                       tolerance=tolerance)


def _one_name(arrays: dict, field: str, *, path: Path) -> str:
    names = [name for name in arrays if name == field or name.endswith("." + field)]
    if len(names) == 1:
        return names[0]
    held = ", ".join(sorted(name or "(the array)" for name in arrays)) or "no arrays"
    if not names:
        raise GroundTruthFileError(
            f"ground truth {path}: neither VPR-Bench rows nor a {field} matrix (it holds "
            f"{held})")
    raise GroundTruthFileError(f"ground truth {path}: several {field} matrices ({held})")


def _as_int(value) -> int | None:
    try:
        number = float(value)
    except (TypeError, ValueError):
        return None
    return int(number) if number == int(number) else None


def _spread(counts: np.ndarray) -> str:
    if counts.size == 0:
        return "no"
    return (f"{int(counts.min())}-{int(counts.max())}, median {float(np.median(counts)):g}"
            if counts.min() != counts.max() else f"{int(counts.min())}")
