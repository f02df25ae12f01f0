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


def sequence_bounds(labels):
    """Per frame, the first and last index of its run of equal labels (``None``: one run)."""
    return [(min(j for j in range(len(labels)) if labels[j] == labels[i]),
             max(j for j in range(len(labels)) if labels[j] == labels[i]))
            for i in range(len(labels))]


def window_zscore(column, i, *, half, last, first=0):
    """Eq. 14 of row ``i`` of one column over rows ``max(first, i - half) .. min(last, i +
    half)`` (``ddof=1``); ``inf`` when the window is constant."""
    window = [float(column[k]) for k in range(max(first, i - half), min(last, i + half) + 1)]
    n = len(window)
    mean = sum(window) / n
    var = sum((x - mean) ** 2 for x in window) / (n - 1) if n > 1 else 0.0
    return math.inf if var == 0.0 else (float(column[i]) - mean) / math.sqrt(var)


def loop_enhance(D, *, r_window, reference_sequences=None):
    """Eq. 14 with ``ddof=1`` over rows ``i +- r_window//2`` (clipped at the ends and at the
    bounds of row ``i``'s reference sequence), shifted by the minimum."""
    D = np.asarray(D, dtype=np.float64)
    R, Q = D.shape
    half = r_window // 2
    bounds = sequence_bounds([0] * R if reference_sequences is None else reference_sequences)
    Z = np.zeros((R, Q))
    for q in range(Q):
        for i in range(R):
            first, last = bounds[i]
            Z[i, q] = window_zscore(D[:, q], i, half=half, last=last, first=first)
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


def loop_row_scores(D_hat, T, *, ds, velocities, bounds=None):
    """Query ``T``'s best trajectory score over the velocities for every end row ``s``; every
    row of a trajectory must lie in ``s``'s reference sequence (``bounds``, default one)."""
    per_row = []
    for s in range(D_hat.shape[0]):
        first, last = (0, D_hat.shape[0] - 1) if bounds is None else bounds[s]
        best_s = math.inf
        for v in velocities:
            total = 0.0
            for t in range(T - ds, T + 1):  # eq. 16, ascending time
                k = s - math.floor(round(v * (T - t), 9))
                if not first <= k <= last:
                    total = math.inf
                    break
                total += float(D_hat[k, t])
            if total < best_s:
                best_s = total
        per_row.append(best_s)
    return per_row


def loop_search(D_hat, *, ds, velocities, r_window, reference_sequences=None,
                query_sequences=None):
    """Look-back search: for each query ``T >= ds`` whose ``ds`` earlier queries are of its own
    query sequence, and end row ``s``, every velocity. The uniqueness competitors are the rows
    more than ``r_window//2`` from the match or in another reference sequence."""
    D_hat = np.asarray(D_hat, dtype=np.float64)
    R, Q = D_hat.shape
    half = r_window // 2
    bounds = sequence_bounds([0] * R if reference_sequences is None else reference_sequences)
    q_bounds = sequence_bounds([0] * Q if query_sequences is None else query_sequences)
    match = np.full(Q, -1, dtype=np.int64)
    score = np.full(Q, np.nan)
    ratio = np.full(Q, np.nan)
    for T in range(ds, Q):
        if T - ds < q_bounds[T][0]:
            continue
        per_row = loop_row_scores(D_hat, T, ds=ds, velocities=velocities, bounds=bounds)
        b, s_best = _first_min(per_row)
        if s_best < 0:
            continue
        second = min([per_row[s] for s in range(R)
                      if abs(s - s_best) > half or bounds[s] != bounds[s_best]],
                     default=math.inf)
        match[T] = s_best
        score[T] = b
        ratio[T] = _ratio(b, second)
    return match, score, ratio


def loop_single_frame(D, *, r_window, reference_sequences=None):
    D = np.asarray(D, dtype=np.float64)
    R, Q = D.shape
    half = r_window // 2
    bounds = sequence_bounds([0] * R if reference_sequences is None else reference_sequences)
    match = np.empty(Q, dtype=np.int64)
    ratio = np.empty(Q)
    for q in range(Q):
        column = [float(D[r, q]) for r in range(R)]
        b, s = _first_min(column)
        second = min([column[r] for r in range(R)
                      if abs(r - s) > half or bounds[r] != bounds[s]], default=math.inf)
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
