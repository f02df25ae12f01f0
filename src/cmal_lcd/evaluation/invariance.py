"""Is a code weather-invariant? Same place vs other places, both across weathers.

For a reference drive and a query drive under different weathers, with codes normalised as the
method's matching protocol normalises them, and ``D[r, q]`` the method's frame difference
(eq. 13 for codes, SAD for thumbnails):

- ``same_place``: mean of ``D[truth[q], q]`` over queries whose place is in the reference;
- ``other_place``: mean of ``D[r, q]`` over the same queries and every reference row farther
  than ``d_thresh`` frames from ``truth[q]`` (a different place, also across weathers);
- ``ratio = same_place / other_place``: below 1 the place dominates the code, near or above 1
  the weather does; it is scale-free, so methods with codes of different magnitudes compare;
- ``single_frame_recall_at_1``: share of those queries whose nearest reference frame lies
  within ``d_thresh`` frames of the true place (no sequence).

Both distances are across weathers, so a per-weather offset of the codes (which a drive-wide
statistic would count as "other place under the same weather") cannot make a code look
invariant or not.
"""

from __future__ import annotations

import numpy as np

from cmal_lcd.data.ground_truth import ReferenceSets


def cross_weather_separation(D: np.ndarray, truth: np.ndarray | ReferenceSets, *,
                             d_thresh: int) -> dict:
    """Same-place vs other-place differences of one cross-weather drive pair.

    Parameters
    ----------
    D : ndarray (R, Q)
        Differences, rows = reference frames, columns = query frames; finite.
    truth : ndarray, int (Q,), or ReferenceSets
        True reference row of every query, ``-1`` where the place is not in the reference;
        or a ground-truth file's right (and ignored) rows (:func:`_separation_of_sets`).
    d_thresh : int
        Rows within ``d_thresh`` of the true row count as the same place (Table I; index
        truth only).

    Returns
    -------
    dict
        ``same_place, other_place, ratio, single_frame_recall_at_1, n_queries``; NaN values
        when no query has a true place (``n_queries`` 0) or no other-place row exists.
    """
    D = np.asarray(D, dtype=np.float64)
    if isinstance(truth, ReferenceSets):
        return _separation_of_sets(D, truth)
    truth = np.asarray(truth, dtype=np.int64)
    if D.ndim != 2 or truth.shape != (D.shape[1],):
        raise ValueError(f"D/truth: expected (R, Q) and (Q,), got {D.shape} and {truth.shape}")
    if not np.all(np.isfinite(D)):
        raise ValueError("D: expected finite differences")
    cols = np.flatnonzero(truth >= 0)
    nan = float("nan")
    if len(cols) == 0:
        return {"same_place": nan, "other_place": nan, "ratio": nan,
                "single_frame_recall_at_1": nan, "n_queries": 0}
    sub, t = D[:, cols], truth[cols]
    rows = np.arange(D.shape[0])[:, None]
    other = np.abs(rows - t[None, :]) > d_thresh
    same = float(sub[t, np.arange(len(cols))].mean())
    other_mean = float(sub[other].mean()) if other.any() else nan
    ratio = same / other_mean if np.isfinite(other_mean) and other_mean > 0 else nan
    hit = np.abs(np.argmin(sub, axis=0) - t) <= d_thresh
    return {"same_place": same, "other_place": other_mean, "ratio": float(ratio),
            "single_frame_recall_at_1": float(hit.mean()), "n_queries": int(len(cols))}


def _separation_of_sets(D: np.ndarray, truth: ReferenceSets) -> dict:
    """:func:`cross_weather_separation` with a ground-truth file's sets: ``same_place`` the mean
    over queries of the mean difference to their right rows, ``other_place`` the mean over the
    rows neither right nor ignored, a single-frame hit a right argmin."""
    if D.ndim != 2 or D.shape != (truth.n_reference, truth.n_query):
        raise ValueError(f"D/truth: expected ({truth.n_reference}, {truth.n_query}), got "
                         f"{D.shape}")
    if not np.all(np.isfinite(D)):
        raise ValueError("D: expected finite differences")
    every = np.tile(np.arange(D.shape[0]), (D.shape[1], 1))  # (Q, R)
    right, ignored = truth.is_right(every).T, truth.is_ignored(every).T  # (R, Q)
    cols = np.flatnonzero(right.any(axis=0))
    nan = float("nan")
    if len(cols) == 0:
        return {"same_place": nan, "other_place": nan, "ratio": nan,
                "single_frame_recall_at_1": nan, "n_queries": 0}
    sub, hits = D[:, cols], right[:, cols]
    same = float(np.mean((sub * hits).sum(axis=0) / hits.sum(axis=0)))
    other = ~(right | ignored)[:, cols]
    other_mean = float(sub[other].mean()) if other.any() else nan
    ratio = same / other_mean if np.isfinite(other_mean) and other_mean > 0 else nan
    hit = hits[np.argmin(sub, axis=0), np.arange(len(cols))]
    return {"same_place": same, "other_place": other_mean, "ratio": float(ratio),
            "single_frame_recall_at_1": float(hit.mean()), "n_queries": int(len(cols))}
