"""Plain-loop reference implementation of SeqSLAM, written from the definitions, for tiny inputs.

Every function follows the conventions of :mod:`cmal_lcd.matching.seqslam` literally, in
float64 Python scalars, with no vectorisation, chunking or algebraic shortcut, so the library
can be checked against it.
"""

from __future__ import annotations

import math

import numpy as np


def loop_difference(reference, query, *, metric):
    """``D[r, q]`` in float64: mean absolute difference or squared Euclidean distance."""
    R, Q = len(reference), len(query)
    D = np.zeros((R, Q))
    for r in range(R):
        for q in range(Q):
            a = [float(v) for v in reference[r]]
            b = [float(v) for v in query[q]]
            if metric == "sad":
                D[r, q] = sum(abs(x - y) for x, y in zip(a, b)) / len(a)
            else:
                D[r, q] = sum((x - y) ** 2 for x, y in zip(a, b))
    return D


def window_zscore(column, i, *, half, last):
    """Eq. 14 of row ``i`` of one column over rows ``max(0, i - half) .. min(last, i + half)``
    (``ddof=1``); ``inf`` when the window is constant."""
    window = [float(column[k]) for k in range(max(0, i - half), min(last, i + half) + 1)]
    n = len(window)
    mean = sum(window) / n
    var = sum((x - mean) ** 2 for x in window) / (n - 1) if n > 1 else 0.0
    return math.inf if var == 0.0 else (float(column[i]) - mean) / math.sqrt(var)


def loop_enhance(D, *, r_window):
    """Eq. 14 with ``ddof=1`` over rows ``i +- r_window//2`` (clipped), shifted by the minimum."""
    D = np.asarray(D, dtype=np.float64)
    R, Q = D.shape
    half = r_window // 2
    Z = np.zeros((R, Q))
    for q in range(Q):
        for i in range(R):
            Z[i, q] = window_zscore(D[:, q], i, half=half, last=R - 1)
    finite = [z for z in Z.ravel() if math.isfinite(z)]
    if finite:
        m = min(finite)
        Z = np.where(np.isfinite(Z), Z - m, Z)
    return Z


def loop_velocities(v_min, v_max, v_step):
    out, i = [], 0
    while True:
        v = round(v_min + i * v_step, 9)
        if v > v_max + 1e-12:
            return out
        out.append(v)
        i += 1


def loop_row_scores(D_hat, T, *, ds, velocities):
    """Query ``T``'s best trajectory score over the velocities for every end row ``s``."""
    per_row = []
    for s in range(D_hat.shape[0]):
        best_s = math.inf
        for v in velocities:
            total = 0.0
            for t in range(T - ds, T + 1):  # eq. 16, ascending time
                k = s - math.floor(round(v * (T - t), 9))
                if k < 0:
                    total = math.inf
                    break
                total += float(D_hat[k, t])
            if total < best_s:
                best_s = total
        per_row.append(best_s)
    return per_row


def loop_search(D_hat, *, ds, velocities, r_window):
    """Look-back search: for each query ``T >= ds`` and end row ``s``, every velocity."""
    D_hat = np.asarray(D_hat, dtype=np.float64)
    R, Q = D_hat.shape
    half = r_window // 2
    match = np.full(Q, -1, dtype=np.int64)
    score = np.full(Q, np.nan)
    ratio = np.full(Q, np.nan)
    for T in range(ds, Q):
        per_row = loop_row_scores(D_hat, T, ds=ds, velocities=velocities)
        b, s_best = _first_min(per_row)
        if s_best < 0:
            continue
        second = min([per_row[s] for s in range(R) if abs(s - s_best) > half], default=math.inf)
        match[T] = s_best
        score[T] = b
        ratio[T] = _ratio(b, second)
    return match, score, ratio


def loop_single_frame(D, *, r_window):
    D = np.asarray(D, dtype=np.float64)
    R, Q = D.shape
    half = r_window // 2
    match = np.empty(Q, dtype=np.int64)
    ratio = np.empty(Q)
    for q in range(Q):
        column = [float(D[r, q]) for r in range(R)]
        b, s = _first_min(column)
        second = min([column[r] for r in range(R) if abs(r - s) > half], default=math.inf)
        match[q] = s
        ratio[q] = _ratio(b, second)
    return match, ratio


def _first_min(values):
    best, index = math.inf, -1
    for i, v in enumerate(values):
        if v < best:
            best, index = v, i
    return best, index


def _ratio(best, second):
    if math.isinf(second):
        return 0.0
    if second == 0.0:
        return 1.0
    return best / second
