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
