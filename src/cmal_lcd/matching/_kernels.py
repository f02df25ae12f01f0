"""numba kernels behind :mod:`cmal_lcd.matching` (private; the public functions validate inputs).

All kernels work on **query-major** arrays ``X[q, r]`` (one contiguous row of ``R`` reference
values per query), the transpose of the public ``D[r, q]``: every SeqSLAM step is per query
column, so rows are what a stream of query chunks produces. Each output cell is computed by one
thread in a fixed order, so results do not depend on the number of threads or on the chunking
of the queries.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange


@njit(parallel=True, fastmath=True, cache=True)
def sad_rows(query, reference, out, block):  # pragma: no cover - compiled
    """``out[q, r] = mean_k |query[q, k] - reference[r, k]|`` (float32 accumulation).

    ``query (Qc, F)``, ``reference (R, F)``, ``out (Qc, R)``, all float32 C-contiguous. Threads
    take blocks of ``block`` reference rows (kept in cache while every query streams past); a
    4-query x 4-reference micro-kernel computes 16 sums at once (1.5x faster than 1 x 4 here).
    Every cell goes through the same micro-kernel, a short last group repeating its last row, so
    a cell's value does not depend on where it falls in a block or a chunk of queries.
    """
    n_query, n_feat = query.shape
    n_ref = reference.shape[0]
    n_blocks = (n_ref + block - 1) // block
    scale = np.float32(1.0) / np.float32(n_feat)
    last_q = n_query - 1
    for b in prange(n_blocks):
        j0 = b * block
        j1 = min(n_ref, j0 + block)
        i = 0
        while i < n_query:
            i1 = min(i + 1, last_q)
            i2 = min(i + 2, last_q)
            i3 = min(i + 3, last_q)
            qa = query[i]
            qb = query[i1]
            qc = query[i2]
            qd = query[i3]
            j = j0
            while j < j1:
                ja = min(j + 1, j1 - 1)
                jb = min(j + 2, j1 - 1)
                jc = min(j + 3, j1 - 1)
                r0 = reference[j]
                r1 = reference[ja]
                r2 = reference[jb]
                r3 = reference[jc]
                s0 = s1 = s2 = s3 = np.float32(0.0)
                t0 = t1 = t2 = t3 = np.float32(0.0)
                u0 = u1 = u2 = u3 = np.float32(0.0)
                w0 = w1 = w2 = w3 = np.float32(0.0)
                for k in range(n_feat):
                    a0 = r0[k]
                    a1 = r1[k]
                    a2 = r2[k]
                    a3 = r3[k]
                    x = qa[k]
                    s0 += abs(x - a0)
                    s1 += abs(x - a1)
                    s2 += abs(x - a2)
                    s3 += abs(x - a3)
                    x = qb[k]
                    t0 += abs(x - a0)
                    t1 += abs(x - a1)
                    t2 += abs(x - a2)
                    t3 += abs(x - a3)
                    x = qc[k]
                    u0 += abs(x - a0)
                    u1 += abs(x - a1)
                    u2 += abs(x - a2)
                    u3 += abs(x - a3)
                    x = qd[k]
                    w0 += abs(x - a0)
                    w1 += abs(x - a1)
                    w2 += abs(x - a2)
                    w3 += abs(x - a3)
                out[i, j] = s0 * scale
                out[i, ja] = s1 * scale
                out[i, jb] = s2 * scale
                out[i, jc] = s3 * scale
                out[i1, j] = t0 * scale
                out[i1, ja] = t1 * scale
                out[i1, jb] = t2 * scale
                out[i1, jc] = t3 * scale
                out[i2, j] = u0 * scale
                out[i2, ja] = u1 * scale
                out[i2, jb] = u2 * scale
                out[i2, jc] = u3 * scale
                out[i3, j] = w0 * scale
                out[i3, ja] = w1 * scale
                out[i3, jb] = w2 * scale
                out[i3, jc] = w3 * scale
                j += 4
            i += 4


@njit(cache=True)
def finite_min(x):  # pragma: no cover - compiled
    """Minimum of the finite values of a 2-D array (``+inf`` when there are none)."""
    best = np.inf
    for i in range(x.shape[0]):
        row = x[i]
        for j in range(row.shape[0]):
            v = row[j]
            if v < best and v > -np.inf:
                best = v
    return best


@njit(parallel=True, cache=True)
def enhance_rows(rows, half, block_lo, block_hi, out):  # pragma: no cover - compiled
    """Local contrast enhancement (eq. 14) of every row, float64 out, unshifted.

    For each query row ``x`` (``R`` reference values) and reference index ``i``: window
    ``lo = max(block_lo[i], i - half) .. hi = min(block_hi[i], i + half)`` (``block_lo``,
    ``block_hi``: int64 ``(R,)`` first and last row of ``i``'s reference sequence; ``0`` and
    ``R - 1`` for one sequence), ``mean`` and sample ``std`` (``ddof=1``) of ``x[lo..hi]``;
    ``out[i] = (x[i] - mean) / std``, or ``+inf`` when ``std == 0`` (constant window, including
    one-value windows). Sums run over the window in ascending order.
    """
    n, R = rows.shape
    inner_lo = half
    inner_hi = R - half  # rows [inner_lo, inner_hi) have full windows
    width = 2 * half + 1
    for q in prange(n):
        x = rows[q]
        o = out[q]
        mean = np.empty(R)
        acc = np.zeros(R)
        # full windows, vectorised over i
        if inner_hi > inner_lo:
            # 0-based loops over views: no negative-index wraparound, so LLVM vectorises them
            m_in = inner_hi - inner_lo
            acc_in = acc[inner_lo:inner_hi]
            mean_in = mean[inner_lo:inner_hi]
            for k in range(width):  # window offset k - half, ascending
                xs = x[k:k + m_in]
                for i in range(m_in):
                    acc_in[i] += xs[i]
            for i in range(m_in):
                mean_in[i] = acc_in[i] / width
                acc_in[i] = 0.0
            for k in range(width):
                xs = x[k:k + m_in]
                for i in range(m_in):
                    d = xs[i] - mean_in[i]
                    acc_in[i] += d * d
            x_in = x[inner_lo:inner_hi]
            o_in = o[inner_lo:inner_hi]
            for i in range(m_in):
                var = acc_in[i] / (width - 1)
                if var > 0.0:
                    o_in[i] = (x_in[i] - mean_in[i]) / np.sqrt(var)
                else:
                    o_in[i] = np.inf
        # windows clipped at both ends and at sequence boundaries
        for i in range(R):
            if inner_lo <= i < inner_hi and block_lo[i] <= i - half and i + half <= block_hi[i]:
                continue
            lo = max(block_lo[i], i - half)
            hi = min(block_hi[i], i + half)
            count = hi - lo + 1
            if count < 2:
                o[i] = np.inf
                continue
            s = 0.0
            for k in range(lo, hi + 1):
                s += x[k]
            m = s / count
            s = 0.0
            for k in range(lo, hi + 1):
                d = x[k] - m
                s += d * d
            var = s / (count - 1)
            if var > 0.0:
                o[i] = (x[i] - m) / np.sqrt(var)
            else:
                o[i] = np.inf


@njit(cache=True)
def _best_and_second(values, half, block_lo, block_hi):  # pragma: no cover - compiled
    """First argmin of ``values`` and the minimum outside ``[argmin - half, argmin + half]``
    clipped to the argmin's reference sequence ``[block_lo[argmin], block_hi[argmin]]`` (rows of
    other sequences always compete).

    Returns ``(index, best, second)``; ``index = -1`` when every value is ``+inf``.
    """
    R = values.shape[0]
    best = np.inf
    index = -1
    for s in range(R):
        if values[s] < best:
            best = values[s]
            index = s
    second = np.inf
    if index >= 0:
        for s in range(0, max(block_lo[index], index - half)):
            if values[s] < second:
                second = values[s]
        for s in range(min(block_hi[index], index + half) + 1, R):
            if values[s] < second:
                second = values[s]
    return index, best, second


@njit(parallel=True, cache=True)
def best_rows(rows, half, block_lo, block_hi, match, best, second):  # pragma: no cover
    """Single-frame matching: per row, first argmin, its value and the best outside the window
    (clipped to the argmin's sequence, see :func:`_best_and_second`)."""
    for q in prange(rows.shape[0]):
        i, b, s = _best_and_second(rows[q], half, block_lo, block_hi)
        match[q] = i
        best[q] = b
        second[q] = s


@njit(parallel=True, cache=True)
def search_rows(rows, first, offsets, half, block_lo, block_hi, match, best,
                second):  # pragma: no cover - compiled
    """Look-back sequence search (eqs. 15-16) for the queries ``rows[first:]``.

    ``rows (n, R)`` holds consecutive query columns of the enhanced matrix, query-major;
    ``first >= ds``. For local query ``t`` and end row ``s``, the trajectory of velocity ``v``
    sums ``rows[t - j, s - offsets[v, j]]`` over ``j = ds .. 0`` (ascending time, eq. 16) in
    float64; it is invalid (``+inf``) when its first row ``s - offsets[v, ds]`` is below
    ``block_lo[s]`` (before the matrix, or in an earlier reference sequence: rows are monotone
    along a trajectory, so it then stays in ``s``'s sequence) and ``+inf`` when it crosses an
    excluded (``+inf``) cell. Per ``s`` the best velocity is kept; then ``match``, ``best`` and
    ``second`` (best outside ``[match - half, match + half]`` clipped to ``match``'s sequence,
    ``block_lo`` .. ``block_hi``) of output row ``t - first``. ``match = -1`` when no trajectory
    is valid.
    """
    n, R = rows.shape
    n_v, length = offsets.shape
    ds = length - 1
    for t in prange(first, n):
        per_row = np.full(R, np.inf)
        acc = np.empty(R)
        for v in range(n_v):
            o_max = offsets[v, ds]
            if o_max >= R:
                continue
            m_valid = R - o_max
            acc_v = acc[o_max:]
            best_v = per_row[o_max:]
            for s in range(m_valid):
                acc_v[s] = 0.0
            for j in range(ds, -1, -1):
                # column t - j, rows s - offsets[v, j] for s >= o_max; 0-based view loop so
                # that LLVM vectorises it (no negative-index wraparound)
                o = offsets[v, j]
                col = rows[t - j, o_max - o:R - o]
                for s in range(m_valid):
                    acc_v[s] += col[s]
            lo_v = block_lo[o_max:]
            for s in range(m_valid):
                if acc_v[s] < best_v[s] and lo_v[s] <= s:
                    best_v[s] = acc_v[s]
        i, b, s2 = _best_and_second(per_row, half, block_lo, block_hi)
        match[t - first] = i
        best[t - first] = b
        second[t - first] = s2
