"""Ground truth for loop closure: the true place of every query in the reference, or ``-1``.

``truth[q]`` is the index of query ``q``'s place in the reference sequence, or ``-1`` when the
place is not in the reference at all (the query is then a negative: any match it gets is a false
positive). Two sources:

- frame correspondence (paired sequences, e.g. Nordland): ``truth[q] = q`` while
  ``q < n_reference``;
- poses: the nearest reference pose, when within ``max_distance`` metres.
"""

from __future__ import annotations

import numpy as np


def ground_truth_from_correspondence(n_reference: int, n_query: int) -> np.ndarray:
    """Ground truth for sequences paired by index.

    Parameters
    ----------
    n_reference, n_query : int
        Sequence lengths.

    Returns
    -------
    numpy.ndarray
        ``int64 (n_query,)``: ``q`` if ``q < n_reference`` else ``-1``.
    """
    for name, value in (("n_reference", n_reference), ("n_query", n_query)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
            raise ValueError(f"{name} must be a non-negative integer, got {value!r}")
    truth = np.arange(n_query, dtype=np.int64)
    truth[truth >= n_reference] = -1
    return truth


def ground_truth_from_poses(reference_xy: np.ndarray, query_xy: np.ndarray, *,
                            max_distance: float) -> np.ndarray:
    """Ground truth from planar positions: the nearest reference pose within a distance.

    Parameters
    ----------
    reference_xy : numpy.ndarray
        ``(R, 2)`` reference positions, metres.
    query_xy : numpy.ndarray
        ``(Q, 2)`` query positions, metres.
    max_distance : float
        A query farther than this from every reference pose gets ``-1``.

    Returns
    -------
    numpy.ndarray
        ``int64 (Q,)``: index of the nearest reference pose (the lowest index on ties), or
        ``-1`` when its distance exceeds ``max_distance``.
    """
    ref = _check_xy(reference_xy, name="reference_xy")
    qry = _check_xy(query_xy, name="query_xy")
    if not np.isfinite(max_distance) or max_distance < 0:
        raise ValueError(f"max_distance must be a finite number >= 0, got {max_distance!r}")
    truth = np.empty(qry.shape[0], dtype=np.int64)
    step = max(1, (4 * 2**20) // max(1, ref.shape[0]))  # about 32 MB of float64 per chunk
    for start in range(0, qry.shape[0], step):
        chunk = qry[start:start + step]
        d2 = ((chunk[:, None, :] - ref[None, :, :]) ** 2).sum(axis=2)
        nearest = d2.argmin(axis=1)
        within = d2[np.arange(chunk.shape[0]), nearest] <= float(max_distance) ** 2
        truth[start:start + step] = np.where(within, nearest, -1)
    return truth


def _check_xy(xy: np.ndarray, *, name: str) -> np.ndarray:
    xy = np.asarray(xy, dtype=np.float64)
    if xy.ndim != 2 or xy.shape[1] != 2:
        raise ValueError(f"{name} must be an (N, 2) array of x, y, got shape {xy.shape}")
    if xy.shape[0] < 1:
        raise ValueError(f"{name} is empty")
    if not np.isfinite(xy).all():
        raise ValueError(f"{name} contains NaN or infinite values")
    return xy


# ------------------------------------------------------------------ one traversal (loops)


def loop_ground_truth_from_poses(xy: np.ndarray, *, pose_tolerance: float,
                                 n_allowed: np.ndarray) -> np.ndarray:
    """Revisits within one traversal: the nearest earlier pose outside the exclusion zone.

    Frame ``r`` is a **revisit** of frame ``q`` when ``r < n_allowed[q]`` (older than the
    exclusion zone, :func:`cmal_lcd.matching.loops.exclusion_limits`) and
    ``|xy[r] - xy[q]| <= pose_tolerance``. A frame with no revisit is a negative (``-1``).

    Parameters
    ----------
    xy : numpy.ndarray
        ``(N, 2)`` positions in metres, in time order.
    pose_tolerance : float
        Metres.
    n_allowed : numpy.ndarray
        ``int (N,)`` allowed earlier rows per frame.

    Returns
    -------
    numpy.ndarray
        ``int64 (N,)``: the revisit nearest in space (the lowest index on ties), or ``-1``.
    """
    return revisit_nearest_to(None, xy, pose_tolerance=pose_tolerance, n_allowed=n_allowed)


def revisit_nearest_to(frames: np.ndarray | None, xy: np.ndarray, *, pose_tolerance: float,
                       n_allowed: np.ndarray) -> np.ndarray:
    """Per frame, the revisit (see :func:`loop_ground_truth_from_poses`) nearest to a given frame.

    Scoring a loop closure by ``|match - truth| <= d_thresh`` needs the revisit closest *in
    index* to the match: on a route driven three times, a match on the first lap is as right as
    one on the second. With ``truth = revisit_nearest_to(match, ...)``,
    :func:`cmal_lcd.evaluation.correct_matches` says whether ``match`` lies within ``d_thresh``
    frames of **any** revisit.

    Parameters
    ----------
    frames : numpy.ndarray or None
        ``int (N,)`` a frame per query (e.g. its match), ``-1`` for none. ``None`` (or ``-1``):
        the revisit nearest in space.
    xy, pose_tolerance, n_allowed
        As in :func:`loop_ground_truth_from_poses`.

    Returns
    -------
    numpy.ndarray
        ``int64 (N,)``: the revisit minimising ``|r - frames[q]|`` (the lower ``r`` on ties), or
        the spatially nearest one where ``frames[q] < 0``; ``-1`` when ``q`` has no revisit.
    """
    xy = _check_xy(xy, name="xy")
    N = xy.shape[0]
    if not np.isfinite(pose_tolerance) or pose_tolerance < 0:
        raise ValueError(f"pose_tolerance must be a finite number >= 0, got {pose_tolerance!r}")
    n_allowed = np.asarray(n_allowed)
    if n_allowed.shape != (N,) or not np.issubdtype(n_allowed.dtype, np.integer):
        raise ValueError(f"n_allowed must be an integer ({N},) array, got {n_allowed.shape}")
    frames = np.full(N, -1, np.int64) if frames is None else np.asarray(frames, np.int64)
    if frames.shape != (N,):
        raise ValueError(f"frames must have shape ({N},), got {frames.shape}")
    truth = np.full(N, -1, dtype=np.int64)
    rows = np.arange(N)
    step = max(1, (4 * 2**20) // N)
    for start in range(0, N, step):
        q = rows[start:start + step]
        d2 = ((xy[q, None, :] - xy[None, :, :]) ** 2).sum(axis=2)
        revisit = (d2 <= float(pose_tolerance) ** 2) & (rows[None, :] < n_allowed[q, None])
        has = revisit.any(axis=1)
        by_space = np.where(revisit, d2, np.inf).argmin(axis=1)
        by_index = np.where(revisit, np.abs(rows[None, :] - frames[q, None]), N + 1).argmin(axis=1)
        chosen = np.where(frames[q] >= 0, by_index, by_space)
        truth[start:start + step] = np.where(has, chosen, -1)
    return truth


# ------------------------------------------------------------------ sets of right references


class ReferenceSets:
    """Ground truth as a set of right reference rows per query (the field's file formats).

    The index form above (``truth[q]`` and a tolerance of ``d_thresh`` frames) says a match
    ``r`` is right when ``|r - truth[q]| <= d_thresh``. The ground-truth files of the field
    (VPR-Bench's ``ground_truth_new.npy``, VPR_Tutorial's ``GThard``/``GTsoft``,
    VPR-methods-evaluation's positives within ``positive_dist_threshold`` metres, MSLS) list
    instead, per query, the reference rows that are right, already with their tolerance.
    This class holds such sets; every metric of :mod:`cmal_lcd.evaluation.metrics` accepts it
    in place of ``truth`` (its ``d_thresh`` then plays no part).

    - **right** rows (``GThard``): a match there is a true positive;
    - **ignored** rows (in ``GTsoft`` but not in ``GThard``): a match there is neither right
      nor wrong; the query is left out of that count (VPR_Tutorial's convention);
    - a query with no right row has no place in the reference: a negative.

    Stored as sorted ``int64`` keys ``q * n_reference + r`` (memory grows with the number of
    right pairs, not with ``R x Q``).

    Parameters
    ----------
    right, ignored : numpy.ndarray
        ``int (M, 2)`` pairs ``(reference row, query row)`` (duplicates allowed); ``ignored``
        may overlap ``right`` (those pairs are right).
    n_reference, n_query : int
        Sequence lengths; every pair must lie inside them.
    source : str
        Where the ground truth comes from (format and file), as written to ``metrics.json``.
    tolerance : str
        Its tolerance in words (``"as listed in the file"``, ``"25 m (UTM)"``), likewise.
    """

    def __init__(self, right: np.ndarray, *, n_reference: int, n_query: int,
                 ignored: np.ndarray | None = None, source: str = "", tolerance: str = ""):
        for name, value in (("n_reference", n_reference), ("n_query", n_query)):
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
                raise ValueError(f"{name} must be a positive integer, got {value!r}")
        self.n_reference, self.n_query = int(n_reference), int(n_query)
        self.source, self.tolerance = str(source), str(tolerance)
        self._right = self._keys(right, name="right")
        soft = self._keys(np.zeros((0, 2), np.int64) if ignored is None else ignored,
                          name="ignored")
        self._ignored = np.setdiff1d(soft, self._right, assume_unique=True)

    # construction ---------------------------------------------------------------------

    @classmethod
    def from_lists(cls, lists, *, n_reference: int, ignored_lists=None, source: str = "",
                   tolerance: str = "") -> "ReferenceSets":
        """From one sequence of right reference rows per query (``len(lists)`` queries)."""
        return cls(_pairs_of_lists(lists, name="lists"), n_reference=n_reference,
                   n_query=len(lists),
                   ignored=None if ignored_lists is None else
                   _pairs_of_lists(ignored_lists, name="ignored_lists"),
                   source=source, tolerance=tolerance)

    @classmethod
    def from_matrices(cls, hard, soft=None, *, source: str = "",
                      tolerance: str = "") -> "ReferenceSets":
        """From boolean (or 0/1) matrices ``(R, Q)``: reference x query, as VPR_Tutorial's
        ``GThard`` and ``GTsoft`` (dense NumPy arrays or SciPy sparse matrices)."""
        right, shape = _nonzero_pairs(hard, name="GThard")
        ignored = None
        if soft is not None:
            ignored, soft_shape = _nonzero_pairs(soft, name="GTsoft")
            if soft_shape != shape:
                raise ValueError(f"GTsoft: shape {soft_shape} differs from GThard's {shape}")
        return cls(right, n_reference=shape[0], n_query=shape[1], ignored=ignored,
                   source=source, tolerance=tolerance)

    @classmethod
    def from_truth(cls, truth: np.ndarray, *, d_thresh: int, n_reference: int,
                   source: str = "", tolerance: str = "") -> "ReferenceSets":
        """The index form as sets: rows within ``d_thresh`` of ``truth[q]`` (none if ``-1``)."""
        truth = np.asarray(truth, dtype=np.int64)
        offsets = np.arange(-int(d_thresh), int(d_thresh) + 1)
        rows = truth[:, None] + offsets[None, :]
        queries = np.broadcast_to(np.arange(truth.size)[:, None], rows.shape)
        keep = (truth[:, None] >= 0) & (rows >= 0) & (rows < n_reference)
        return cls(np.stack([rows[keep], queries[keep]], axis=1), n_reference=n_reference,
                   n_query=truth.size, source=source,
                   tolerance=tolerance or f"{int(d_thresh)} frames")

    def subset(self, reference_rows: np.ndarray, query_rows: np.ndarray) -> "ReferenceSets":
        """The ground truth between selected frames: ``reference_rows`` and ``query_rows``
        (``int``, positions in this object's frames, each strictly increasing) become
        ``0..len-1``; right and ignored pairs outside the selection are dropped (a query whose
        right references were not selected has no place in the selected reference)."""
        reference_rows = self._increasing(reference_rows, self.n_reference, "reference_rows")
        query_rows = self._increasing(query_rows, self.n_query, "query_rows")
        new_ref = np.full(self.n_reference, -1, np.int64)
        new_ref[reference_rows] = np.arange(reference_rows.size)
        new_query = np.full(self.n_query, -1, np.int64)
        new_query[query_rows] = np.arange(query_rows.size)

        def kept(keys: np.ndarray) -> np.ndarray:
            r, q = new_ref[keys % self.n_reference], new_query[keys // self.n_reference]
            keep = (r >= 0) & (q >= 0)
            return np.stack([r[keep], q[keep]], axis=1)

        return ReferenceSets(kept(self._right), n_reference=reference_rows.size,
                             n_query=query_rows.size, ignored=kept(self._ignored),
                             source=self.source, tolerance=self.tolerance)

    def to_arrays(self) -> dict[str, np.ndarray]:
        """Plain arrays that :meth:`from_arrays` reads back (for an ``.npz``): ``right`` and
        ``ignored`` ``int64 (M, 2)`` (reference, query) pairs and ``shape`` ``(R, Q)``."""
        def pairs(keys: np.ndarray) -> np.ndarray:
            return np.stack([keys % self.n_reference, keys // self.n_reference], axis=1)

        return {"right": pairs(self._right), "ignored": pairs(self._ignored),
                "shape": np.array([self.n_reference, self.n_query], np.int64)}

    @classmethod
    def from_arrays(cls, arrays, *, source: str = "", tolerance: str = "") -> "ReferenceSets":
        """The inverse of :meth:`to_arrays`."""
        n_reference, n_query = (int(v) for v in np.asarray(arrays["shape"]))
        return cls(np.asarray(arrays["right"]).reshape(-1, 2), n_reference=n_reference,
                   n_query=n_query, ignored=np.asarray(arrays["ignored"]).reshape(-1, 2),
                   source=source, tolerance=tolerance)

    @staticmethod
    def _increasing(rows, n: int, name: str) -> np.ndarray:
        rows = np.asarray(rows, dtype=np.int64).reshape(-1)
        if rows.size == 0 or rows[0] < 0 or rows[-1] >= n or np.any(np.diff(rows) <= 0):
            raise ValueError(f"{name}: expected strictly increasing positions in 0..{n - 1}")
        return rows

    # queries --------------------------------------------------------------------------

    def is_right(self, rows: np.ndarray) -> np.ndarray:
        """``bool`` of the shape of ``rows`` (``(Q,)`` or ``(Q, K)``, ``-1`` = none): whether
        each row is a right reference of the query of its first axis."""
        return self._contains(self._right, rows)

    def is_ignored(self, rows: np.ndarray) -> np.ndarray:
        """Like :meth:`is_right`, for the rows that are neither right nor wrong."""
        return self._contains(self._ignored, rows)

    def has_place(self) -> np.ndarray:
        """``bool (Q,)``: the query has at least one right reference row."""
        out = np.zeros(self.n_query, dtype=bool)
        out[self._right // self.n_reference] = True
        return out

    def right_rows(self, q: int) -> np.ndarray:
        """``int64`` the right reference rows of query ``q``, ascending."""
        lo, hi = np.searchsorted(self._right, [q * self.n_reference, (q + 1) * self.n_reference])
        return self._right[lo:hi] - q * self.n_reference

    def nearest_right(self, rows: np.ndarray | None = None) -> np.ndarray:
        """``int64 (Q,)`` per query the right row nearest to ``rows[q]`` (its first right row
        where ``rows`` is None or ``-1``), ``-1`` when it has none: a "true place" to draw."""
        out = np.full(self.n_query, -1, dtype=np.int64)
        q_of = self._right // self.n_reference
        r_of = self._right % self.n_reference
        starts = np.searchsorted(q_of, np.arange(self.n_query))
        ends = np.searchsorted(q_of, np.arange(self.n_query), side="right")
        for q in np.flatnonzero(ends > starts):
            candidates = r_of[starts[q]:ends[q]]
            target = -1 if rows is None else int(rows[q])
            out[q] = candidates[0] if target < 0 else candidates[np.argmin(
                np.abs(candidates - target))]
        return out

    def describe(self) -> dict:
        """``{"source", "tolerance", "n_right_pairs", "n_ignored_pairs"}`` for ``metrics.json``."""
        return {"source": self.source, "tolerance": self.tolerance,
                "n_right_pairs": int(self._right.size),
                "n_ignored_pairs": int(self._ignored.size)}

    # helpers --------------------------------------------------------------------------

    def _keys(self, pairs: np.ndarray, *, name: str) -> np.ndarray:
        pairs = np.asarray(pairs)
        if pairs.size == 0:
            return np.zeros(0, dtype=np.int64)
        if pairs.ndim != 2 or pairs.shape[1] != 2 or not np.issubdtype(pairs.dtype, np.integer):
            raise ValueError(f"{name}: expected integer (M, 2) pairs (reference, query), got "
                             f"{pairs.dtype} {pairs.shape}")
        r, q = pairs[:, 0].astype(np.int64), pairs[:, 1].astype(np.int64)
        for what, values, n in (("reference", r, self.n_reference), ("query", q, self.n_query)):
            bad = (values < 0) | (values >= n)
            if bad.any():
                raise ValueError(f"{what} index {int(values[bad][0])} outside 0..{n - 1} "
                                 f"({n} {what} frames; {name} pairs)")
        return np.unique(q * self.n_reference + r)

    def _contains(self, keys: np.ndarray, rows: np.ndarray) -> np.ndarray:
        rows = np.asarray(rows)
        if rows.ndim not in (1, 2) or rows.shape[0] != self.n_query \
                or not np.issubdtype(rows.dtype, np.integer):
            raise ValueError(f"rows: expected an integer ({self.n_query},) or ({self.n_query}, "
                             f"K) array, got {rows.dtype} {rows.shape}")
        q = np.arange(self.n_query).reshape((-1,) + (1,) * (rows.ndim - 1))
        valid = (rows >= 0) & (rows < self.n_reference)
        wanted = q * self.n_reference + np.where(valid, rows, 0)
        if keys.size == 0:
            return np.zeros(rows.shape, dtype=bool)
        at = np.minimum(np.searchsorted(keys, wanted), keys.size - 1)
        return valid & (keys[at] == wanted)


def _pairs_of_lists(lists, *, name: str) -> np.ndarray:
    """``int64 (M, 2)`` (reference, query) pairs from one list of reference rows per query."""
    pairs = []
    for q, rows in enumerate(lists):
        rows = np.asarray(rows).reshape(-1)
        if rows.size and not np.issubdtype(rows.dtype, np.integer):
            if np.issubdtype(rows.dtype, np.floating) and np.all(rows == np.round(rows)):
                rows = rows.astype(np.int64)
            else:
                raise ValueError(f"{name}[{q}]: reference indices must be integers, got "
                                 f"{rows.dtype}")
        pairs.append(np.stack([rows.astype(np.int64), np.full(rows.size, q, np.int64)], axis=1))
    return np.concatenate(pairs) if pairs else np.zeros((0, 2), np.int64)


def _nonzero_pairs(matrix, *, name: str) -> tuple[np.ndarray, tuple[int, int]]:
    """``(int64 (M, 2) nonzero (row, column) pairs, shape)`` of a dense or sparse 2-D matrix."""
    if hasattr(matrix, "tocoo"):  # scipy.sparse
        coo = matrix.tocoo()
        keep = coo.data != 0
        return np.stack([coo.row[keep], coo.col[keep]], axis=1).astype(np.int64), coo.shape
    matrix = np.asarray(matrix)
    if matrix.ndim != 2:
        raise ValueError(f"{name}: expected a 2-D (reference x query) matrix, got shape "
                         f"{matrix.shape}")
    if matrix.dtype != np.bool_ and not np.issubdtype(matrix.dtype, np.number):
        raise ValueError(f"{name}: expected a boolean or numeric matrix, got {matrix.dtype}")
    if np.issubdtype(matrix.dtype, np.floating) and not np.isfinite(matrix).all():
        raise ValueError(f"{name}: holds NaN or infinite values")
    return np.argwhere(matrix != 0).astype(np.int64), matrix.shape
