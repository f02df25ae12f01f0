"""Is a code condition-invariant? Distances within a place across weathers vs across places.

A code is weather-invariant for place recognition when two frames of the same place under
different weathers are closer than two frames of different places under the same weather.
:func:`code_invariance` measures both mean squared Euclidean distances (eq. 13, the distance
SeqSLAM uses on codes) and their ratio: below 1 the place dominates the code, above 1 the
weather does. The ratio is scale-free, so methods with codes of different magnitudes compare.

The means are computed exactly from per-group sums (``O(N F)``), never from the ``N x N``
distance matrix: for groups ``P`` and ``Q``,
``sum_{i in P, j in Q} ||x_i - x_j||^2 = |Q| sum_P ||x_i||^2 + |P| sum_Q ||x_j||^2
- 2 (sum_P x_i) . (sum_Q x_j)``.
"""

from __future__ import annotations

import numpy as np


def _validate(codes: np.ndarray, place: np.ndarray, condition: np.ndarray):
    codes = np.asarray(codes, dtype=np.float64)
    place = np.asarray(place)
    condition = np.asarray(condition)
    if codes.ndim != 2:
        raise ValueError(f"codes: expected shape (N, F), got {codes.shape}")
    n = codes.shape[0]
    for name, arr in (("place", place), ("condition", condition)):
        if arr.shape != (n,):
            raise ValueError(f"{name}: expected shape ({n},), got {arr.shape}")
        if not np.issubdtype(arr.dtype, np.integer):
            raise ValueError(f"{name}: expected integer ids, got dtype {arr.dtype}")
    if not np.all(np.isfinite(codes)):
        raise ValueError("codes: expected finite values")
    return codes, place, condition


def _group_stats(codes: np.ndarray, keys: np.ndarray):
    """Per unique key (rows of ``keys``): count, sum of codes, sum of squared norms."""
    uniq, inverse = np.unique(keys, axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    count = np.bincount(inverse, minlength=len(uniq)).astype(np.float64)
    total = np.zeros((len(uniq), codes.shape[1]))
    np.add.at(total, inverse, codes)
    sq = np.bincount(inverse, weights=np.einsum("ij,ij->i", codes, codes), minlength=len(uniq))
    return uniq, count, total, sq


def _within_pair_sum(count, total, sq):
    """Sum over unordered pairs within each group of ``||x_i - x_j||^2`` (per group)."""
    return count * sq - np.einsum("ij,ij->i", total, total)


def code_invariance(codes: np.ndarray, place: np.ndarray, condition: np.ndarray) -> dict:
    """Mean code distances: same place across weathers vs different places in one weather.

    Parameters
    ----------
    codes : ndarray, shape (N, F)
        One code per frame.
    place : ndarray, int, shape (N,)
        Place id of each frame (frames of one place under several conditions share it).
    condition : ndarray, int, shape (N,)
        Condition (weather) id of each frame.

    Returns
    -------
    dict
        ``same_place_cross_condition``: mean ``||c_i - c_j||^2`` over pairs with the same
        place and different conditions; ``different_place_same_condition``: over pairs with
        different places and the same condition; ``ratio``: the first over the second (lower
        = more invariant); ``n_pairs_same_place``, ``n_pairs_different_place``: the number of
        unordered pairs behind each mean. A mean without pairs is NaN (and so is the ratio).

    Raises
    ------
    ValueError
        Naming ``codes``, ``place`` or ``condition`` when shapes or dtypes are wrong.
    """
    codes, place, condition = _validate(codes, place, condition)
    if codes.shape[0] == 0:
        nan = float("nan")
        return {"same_place_cross_condition": nan, "different_place_same_condition": nan,
                "ratio": nan, "n_pairs_same_place": 0, "n_pairs_different_place": 0}

    # distances do not change under a shift; centring keeps the sums of squares small, so the
    # differences below lose little to cancellation
    codes = codes - codes.mean(axis=0)
    _, n_pc, s_pc, q_pc = _group_stats(codes, np.stack([place, condition], axis=1))
    _, n_p, s_p, q_p = _group_stats(codes, place[:, None])
    _, n_c, s_c, q_c = _group_stats(codes, condition[:, None])

    within_pc = _within_pair_sum(n_pc, s_pc, q_pc).sum()
    pairs_pc = (n_pc * (n_pc - 1) / 2).sum()
    # same place, different condition = pairs within a place minus pairs within (place, cond)
    same_place_sum = _within_pair_sum(n_p, s_p, q_p).sum() - within_pc
    same_place_pairs = (n_p * (n_p - 1) / 2).sum() - pairs_pc
    # same condition, different place = pairs within a condition minus pairs within (place, cond)
    diff_place_sum = _within_pair_sum(n_c, s_c, q_c).sum() - within_pc
    diff_place_pairs = (n_c * (n_c - 1) / 2).sum() - pairs_pc

    same = same_place_sum / same_place_pairs if same_place_pairs > 0 else float("nan")
    diff = diff_place_sum / diff_place_pairs if diff_place_pairs > 0 else float("nan")
    # rounding can leave a tiny negative where every distance is 0
    same, diff = (max(v, 0.0) if np.isfinite(v) else v for v in (same, diff))
    ratio = same / diff if np.isfinite(same) and np.isfinite(diff) and diff > 0 else float("nan")
    return {"same_place_cross_condition": float(same),
            "different_place_same_condition": float(diff),
            "ratio": float(ratio),
            "n_pairs_same_place": int(round(same_place_pairs)),
            "n_pairs_different_place": int(round(diff_place_pairs))}
