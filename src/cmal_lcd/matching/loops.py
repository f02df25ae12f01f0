"""Loop closure within one traversal: SeqSLAM on the self-difference matrix of one sequence.

A robot recognises, during one run, a place it has already visited. Every frame is a query
and the frames before it are its reference; SeqSLAM run naively on ``D = d(X, X)`` matches each
frame to itself or to its immediate past (``D[q, q] = 0``). This module therefore restricts
every query to frames **older than an exclusion zone**.

Conventions (everything else is :mod:`cmal_lcd.matching.seqslam`'s, reused, not copied):

- ``D[r, q]`` = difference between frame ``r`` (reference role) and frame ``q`` (query role) of
  the same sequence, rows and columns ``0 .. N-1``.
- **Exclusion zone** (:func:`exclusion_limits`): query ``q`` may match row ``r`` only when
  ``r < n_allowed[q]``, with ``n_allowed[q]`` the number of frames that are

  - older than ``frames`` frames: ``q - r > frames`` (``frames = 0``: every earlier frame), and
  - when ``metres`` is given, farther back than ``metres`` of travel:
    ``travelled[q] - travelled[r] > metres`` (``travelled`` = cumulative path length,
    non-decreasing, so the allowed rows of every query are a prefix ``0 .. n_allowed[q] - 1``).

  Cells outside the zone are ``+inf`` in the matrix the search sees, so they never match and a
  trajectory that crosses one is invalid (as a constant enhancement window in two-drive
  matching).
- **Enhancement** (eq. 14) per query column over its allowed prefix only: windows are clipped at
  the exclusion boundary exactly as at the matrix ends, so the near-zero differences of recent
  frames never enter the statistics of an allowed cell. The global minimum over every finite
  enhanced cell is subtracted (scores are shifted by ``(ds + 1) * min``, as in
  :func:`~cmal_lcd.matching.match_sequences`).
- **Search, score, uniqueness ratio, single-frame match**: :func:`~cmal_lcd.matching.
  sequence_search`'s look-back search on that matrix, with its guards but one: a scored query
  with **no valid competitor** outside the uniqueness window gets ``ratio = 1`` (the least
  confident value), not 0. In two-drive matching that case means every other row is excluded
  for lack of contrast; here it mostly means the query has just left the exclusion zone and
  has a handful of allowed rows, which is no evidence of a distinctive place (with the guard
  at 0 such queries became the most confident, false, loop closures on Nordland). The same
  holds for the single-frame ratio. A query whose allowed prefix is empty, or with fewer than
  ``ds`` earlier frames, is not scored (``match = -1``).

Memory: the enhanced matrix is held whole as float64, ``8 N^2`` bytes (about 100 MB for 3,600
frames, 800 MB for 10,000).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from cmal_lcd.matching import _kernels
from cmal_lcd.matching.difference import DifferenceRows
from cmal_lcd.matching.params import SeqSLAMParams
from cmal_lcd.matching.seqslam import (MatchResult, SequenceBlocks, _enhanced_rows,
                                       _finite_min, _scores_and_ratios, _search_rows)

#: Default exclusion zone in frames: a query never matches its last 50 frames.
DEFAULT_EXCLUDE_FRAMES = 50


@dataclasses.dataclass(frozen=True)
class LoopResult(MatchResult):
    """Result of :func:`match_loops`, one entry per frame of the sequence: a
    :class:`~cmal_lcd.matching.seqslam.MatchResult` of the sequence against itself, plus
    ``n_allowed`` (the top-K fields stay None).

    Attributes
    ----------
    match : numpy.ndarray
        ``int64 (N,)`` matched earlier frame, ``-1`` when not scored.
    score, ratio : numpy.ndarray
        ``float64 (N,)`` sequence score and uniqueness ratio (lower = more confident); NaN when
        not scored.
    single_frame_match : numpy.ndarray
        ``int64 (N,)`` first argmin of the raw ``D`` column over the allowed rows, ``-1`` when no
        row is allowed.
    single_frame_ratio : numpy.ndarray
        ``float64 (N,)``; NaN when ``single_frame_match`` is ``-1``.
    n_allowed : numpy.ndarray
        ``int64 (N,)`` allowed rows per query (:func:`exclusion_limits`).
    params : SeqSLAMParams
    D, D_hat : numpy.ndarray or None
        ``float32 (N, N)`` raw and enhanced self-difference matrices when ``keep_matrices``,
        ``+inf`` outside the exclusion zone (``D_hat`` is ``D`` when the enhancement is off).
    """

    n_allowed: np.ndarray | None = None


def travelled_distance(xy: np.ndarray) -> np.ndarray:
    """Cumulative path length along a sequence of planar positions.

    Parameters
    ----------
    xy : numpy.ndarray
        ``(N, 2)`` positions in metres, in time order.

    Returns
    -------
    numpy.ndarray
        ``float64 (N,)``: ``0`` at the first frame, then the summed Euclidean steps.
    """
    xy = np.asarray(xy, dtype=np.float64)
    if xy.ndim != 2 or xy.shape[1] != 2 or not np.isfinite(xy).all():
        raise ValueError(f"xy must be a finite (N, 2) array, got shape {xy.shape}")
    steps = np.sqrt((np.diff(xy, axis=0) ** 2).sum(axis=1))
    return np.concatenate([[0.0], np.cumsum(steps)])


def exclusion_limits(n_frames: int, *, frames: int = DEFAULT_EXCLUDE_FRAMES,
                     metres: float | None = None,
                     travelled: np.ndarray | None = None) -> np.ndarray:
    """Number of allowed (old enough) rows of every query: the exclusion zone.

    Parameters
    ----------
    n_frames : int
        ``N``, the sequence length.
    frames : int
        Row ``r`` is allowed for query ``q`` only when ``q - r > frames`` (``>= 0``).
    metres : float, optional
        Also require ``travelled[q] - travelled[r] > metres`` (needs ``travelled``).
    travelled : numpy.ndarray, optional
        ``float (N,)`` cumulative distance, non-decreasing (:func:`travelled_distance`).

    Returns
    -------
    numpy.ndarray
        ``int64 (N,)``: query ``q`` may match rows ``0 .. n_allowed[q] - 1``.
    """
    if isinstance(n_frames, bool) or not isinstance(n_frames, (int, np.integer)) \
            or n_frames < 0:
        raise ValueError(f"n_frames must be an integer >= 0, got {n_frames!r}")
    if isinstance(frames, bool) or not isinstance(frames, (int, np.integer)) or frames < 0:
        raise ValueError(f"frames (exclusion zone) must be an integer >= 0, got {frames!r}")
    q = np.arange(n_frames, dtype=np.int64)
    limit = np.maximum(q - int(frames), 0)
    if metres is None:
        return limit
    if not isinstance(metres, (int, float, np.number)) or not math.isfinite(metres) \
            or metres < 0:
        raise ValueError(f"metres (exclusion zone) must be a finite number >= 0, got {metres!r}")
    if travelled is None:
        raise ValueError("travelled: needed for an exclusion zone in metres (poses)")
    travelled = np.asarray(travelled, dtype=np.float64)
    if travelled.shape != (n_frames,) or not np.isfinite(travelled).all():
        raise ValueError(f"travelled must be a finite ({n_frames},) array, got "
                         f"shape {travelled.shape}")
    if np.any(np.diff(travelled) < 0):
        raise ValueError("travelled must be non-decreasing (cumulative distance)")
    # rows r with travelled[r] < travelled[q] - metres form a prefix
    by_distance = np.searchsorted(travelled, travelled - float(metres), side="left")
    return np.minimum(limit, by_distance.astype(np.int64))


def exclusion_mask(n_allowed: np.ndarray) -> np.ndarray:
    """``bool (N, N)``: ``True`` where ``D[r, q]`` is inside the exclusion zone
    (``r >= n_allowed[q]``)."""
    n_allowed = np.asarray(n_allowed, dtype=np.int64)
    return np.arange(n_allowed.size)[:, None] >= n_allowed[None, :]


def match_loops(features: np.ndarray, *, metric: str, params: SeqSLAMParams | None = None,
                n_allowed: np.ndarray | None = None, keep_matrices: bool = False) -> LoopResult:
    """SeqSLAM loop closure within one sequence, with a temporal exclusion zone.

    Parameters
    ----------
    features : numpy.ndarray
        ``(N, F)`` per-frame features in time order.
    metric : {"sad", "sad_u8", "sqeuclidean", "sqeuclidean_f32"}
        Difference metric (:func:`~cmal_lcd.matching.difference_matrix`).
    params : SeqSLAMParams, optional
        Enhancement, search and score options (default Table I).
    n_allowed : numpy.ndarray, optional
        ``int (N,)`` allowed rows per query (:func:`exclusion_limits`); default
        ``exclusion_limits(N)`` (:data:`DEFAULT_EXCLUDE_FRAMES` frames).
    keep_matrices : bool
        Also return ``D`` and ``D_hat`` (``float32 (N, N)``).

    Returns
    -------
    LoopResult
        See the module docs for every definition.
    """
    params = SeqSLAMParams.defaults() if params is None else params
    if not isinstance(params, SeqSLAMParams):
        raise ValueError(f"params must be a SeqSLAMParams, got {type(params).__name__}")
    op = DifferenceRows(features, metric=metric)
    N = op.n_reference
    n_allowed = exclusion_limits(N) if n_allowed is None else _check_allowed(n_allowed, N)
    d_rows = _masked_difference_rows(op, features, n_allowed)
    half_enh = params.enhancement_window // 2
    z_rows = _enhanced_prefixes(d_rows, n_allowed, half_enh)
    minimum = _finite_min(z_rows) if half_enh else math.inf
    shift = minimum if math.isfinite(minimum) else 0.0

    match = np.full(N, -1, dtype=np.int64)
    best = np.full(N, np.nan)
    second = np.full(N, np.nan)
    if N > params.ds:
        m, b, s = _search_rows(z_rows, first=params.ds, offsets=params.offsets(),
                               half=params.r_window // 2)
        match[params.ds:], best[params.ds:], second[params.ds:] = m, b, s
    score, ratio = _scores_and_ratios(best, second, match, shift=(params.ds + 1) * shift)
    ratio[(match >= 0) & np.isinf(second)] = 1.0  # no competitor: no evidence (module docs)

    sf_match = np.empty(N, dtype=np.int64)
    sf_best = np.empty(N)
    sf_second = np.empty(N)
    one = SequenceBlocks.single(d_rows.shape[1])
    _kernels.best_rows(d_rows, params.r_window // 2, one.lo, one.hi, sf_match, sf_best,
                       sf_second)
    _, sf_ratio = _scores_and_ratios(sf_best, sf_second, sf_match, shift=0.0)
    sf_ratio[(sf_match >= 0) & np.isinf(sf_second)] = 1.0

    D_out = D_hat_out = None
    if keep_matrices:
        D_out = np.ascontiguousarray(d_rows.T)
        if half_enh:
            D_hat_out = np.ascontiguousarray((z_rows - shift).T.astype(np.float32))
        else:
            D_hat_out = D_out
    return LoopResult(match=match, score=score, ratio=ratio, single_frame_match=sf_match,
                      single_frame_ratio=sf_ratio, n_allowed=n_allowed, params=params,
                      D=D_out, D_hat=D_hat_out)


# --------------------------------------------------------------------------------- helpers


def _check_allowed(n_allowed: np.ndarray, n_frames: int) -> np.ndarray:
    n_allowed = np.asarray(n_allowed)
    if n_allowed.shape != (n_frames,) or not np.issubdtype(n_allowed.dtype, np.integer):
        raise ValueError(f"n_allowed must be an integer ({n_frames},) array, got "
                         f"{n_allowed.dtype} {n_allowed.shape}")
    n_allowed = n_allowed.astype(np.int64)
    if np.any(n_allowed < 0) or np.any(n_allowed > np.arange(n_frames)):
        raise ValueError("n_allowed: query q may only match earlier frames "
                         "(0 <= n_allowed[q] <= q)")
    return n_allowed


def _masked_difference_rows(op: DifferenceRows, features: np.ndarray,
                            n_allowed: np.ndarray) -> np.ndarray:
    """``float32 (N, N)`` query-major self-differences, ``+inf`` where ``r >= n_allowed[q]``."""
    features = op.check_query(features)
    N = op.n_reference
    rows = np.empty((N, N), dtype=np.float32)
    step = op.chunk_rows()
    for start in range(0, N, step):
        op(features[start:start + step], out=rows[start:start + step])
    for q, limit in enumerate(n_allowed):
        rows[q, limit:] = np.inf
    return rows


def _enhanced_prefixes(d_rows: np.ndarray, n_allowed: np.ndarray, half: int) -> np.ndarray:
    """``float64 (N, N)``: eq. 14 over each query row's allowed prefix, unshifted; ``+inf`` beyond.

    ``half == 0``: the raw differences (no enhancement).
    """
    if half == 0:
        return d_rows.astype(np.float64)
    z = np.full(d_rows.shape, np.inf)
    for q, limit in enumerate(n_allowed):
        if limit:
            z[q, :limit] = _enhanced_rows(d_rows[q:q + 1, :limit], half)[0]
    return z
