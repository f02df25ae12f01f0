"""SeqSLAM: local contrast enhancement (eq. 14) and look-back sequence search (eqs. 15-16).

Conventions, stated once for the whole package:

- ``D[r, q]``: rows = reference frames, columns = query frames; lower = more alike.
- **Enhancement** (eq. 14), per query column along the reference axis: for row ``i`` the window is
  rows ``i - r_window//2 .. i + r_window//2`` inclusive (11 rows for ``r_window=10``), clipped at
  the ends; ``z = (D - mean) / std`` with the sample std (``ddof=1``), computed in float64. Then
  the global minimum of the finite ``z`` is subtracted so every value is ``>= 0``
  (OpenSeqSLAM). A **constant window** (``std == 0``, e.g. identical black tunnel frames, or a
  one-row window when there is a single reference frame) has no contrast to enhance: its cell is
  set to ``+inf`` and so excluded from the search; the result never holds NaN.
  ``r_window=0`` (or ``enhance=False``) means no enhancement.
- **Trajectories** look back (paper eq. 15): the trajectory for query column ``T`` uses the
  ``ds + 1`` columns ``T - ds .. T`` and ends at reference row ``s`` at column ``T``; at column
  ``t`` it visits row ``k_t = s - floor(v * (T - t))`` (:func:`~cmal_lcd.matching.params.
  trajectory_offsets`). Queries ``T < ds`` have too little history and are not scored
  (``match = -1``, ``score`` and ``ratio`` NaN). Velocities: ``v_min, v_min + v_step, ..
  <= v_max``. A trajectory that leaves the matrix (``k_t < 0``) or crosses an excluded (``+inf``)
  cell is invalid.
- **Score** (eq. 16): the plain sum of the enhanced differences along the trajectory, summed in
  float64 in ascending time; best over velocities, then over ``s`` (the first, lowest ``s`` on
  ties). ``match = s`` of the best trajectory (``-1`` when no trajectory is valid).
- **Uniqueness ratio** (OpenSeqSLAM): ``ratio = best / second`` where ``second`` is the best
  score over rows outside ``[match - r_window//2, match + r_window//2]`` (inclusive). Lower =
  more confident. Guards, so a scored query never gets NaN: ``ratio = 0`` when ``second`` is
  ``+inf`` (no valid competitor: maximally distinctive), ``ratio = 1`` when ``best == second
  == 0`` (indistinguishable).
- **Several sequences on one side** (``match_sequences(..., reference_sequences=,
  query_sequences=)``, e.g. Mapillary SLS, whose query and database sides are many short
  drives): nothing crosses a reference sequence boundary. Enhancement windows are clipped at
  it as at the matrix ends; a trajectory must lie in its end row's sequence; the uniqueness
  window is clipped to the match's sequence (rows of other sequences always compete, so a
  place seen by two reference drives gives a ratio near 1). A query whose ``ds`` earlier
  queries reach into an earlier query sequence is not scored. One sequence per side (the
  default) is everything above unchanged.
- **Single-frame matching** (the baseline): per query, the first argmin of the raw ``D`` column,
  with the same uniqueness ratio on raw differences.
- **Top-K lists** (``match_sequences(..., top_k=K)``, for recall@K): per query, the ``K``
  reference rows with the lowest values in ascending order, ties broken by the lower row (a
  stable sort, so entry 0 is the first argmin: ``match`` / ``single_frame_match``). Sequence
  lists rank end rows ``s`` by their best score over velocities (eq. 16, the values the search
  minimises); single-frame lists rank rows by the raw ``D``. Rows with no valid trajectory
  (``+inf``), entries beyond ``R``, and every entry of an unscored query are ``-1``. Their
  values come with them (``sequence_top_k_score``: the sequence scores, shifted as ``score``, so
  entry 0 is ``score``; ``single_frame_top_k_difference``: the raw ``D`` values), NaN where the
  row is ``-1``.

Streaming (:func:`match_sequences`): the difference and the enhancement are per query column
and the search needs only the previous ``ds`` columns, so the queries are processed in chunks
with an overlap of ``ds`` columns, and no ``R x Q`` matrix is held unless ``keep_matrices``. The
global minimum of the enhancement is only known at the end, but every valid trajectory has
exactly ``ds + 1`` cells, so subtracting ``m`` from every cell lowers every trajectory's sum by
``(ds + 1) m``: the search runs on the unshifted float64 ``z`` and the scores are shifted at the
end (argmins are unchanged; sums agree with the shifted ones to float64 rounding). The search
therefore never sees float32-rounded enhanced values; :func:`enhance_contrast` returns them as
float32 for display and storage.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from collections.abc import Callable

import numpy as np

from numba import njit, prange

from cmal_lcd.matching import _kernels
from cmal_lcd.matching.difference import DifferenceRows
from cmal_lcd.matching.params import (SeqSLAMParams, check_matching, trajectory_offsets,
                                      trajectory_velocities)

logger = logging.getLogger(__name__)


@dataclasses.dataclass(frozen=True)
class SequenceBlocks:
    """The sequences of one side of a matrix whose rows (or columns) hold several sequences,
    one after another (Mapillary SLS: many short drives per city and side).

    Attributes
    ----------
    lo, hi : numpy.ndarray
        ``int64 (N,)`` first and last index of the sequence that holds each index.
    """

    lo: np.ndarray
    hi: np.ndarray

    @classmethod
    def single(cls, n: int) -> SequenceBlocks:
        """``n`` frames of one sequence."""
        return cls(lo=np.zeros(n, dtype=np.int64), hi=np.full(n, n - 1, dtype=np.int64))

    @classmethod
    def from_labels(cls, labels, *, n: int, name: str) -> SequenceBlocks:
        """Blocks from one sequence label per frame (``None``: one sequence of ``n`` frames).

        A sequence is a run of equal labels; a label that comes back after another one is
        refused (``ValueError`` naming ``name``): its frames would not be consecutive.
        """
        if labels is None:
            return cls.single(n)
        labels = np.asarray(labels)
        if labels.ndim != 1 or len(labels) != n:
            raise ValueError(f"{name} must hold one sequence label per frame ({n}), got shape "
                             f"{labels.shape}")
        if n == 0:
            return cls.single(0)
        new = np.ones(n, dtype=bool)
        new[1:] = labels[1:] != labels[:-1]
        starts = np.flatnonzero(new)
        _, first_seen = np.unique(labels[starts], return_index=True)
        if len(first_seen) != len(starts):
            again = np.setdiff1d(np.arange(len(starts)), first_seen)[0]
            raise ValueError(f"{name}: sequence {labels[starts[again]].item()!r} comes back at frame "
                             f"{starts[again]} after other sequences; the frames of a sequence "
                             f"must be consecutive")
        ends = np.append(starts[1:] - 1, n - 1)
        run = np.cumsum(new) - 1
        return cls(lo=starts[run].astype(np.int64), hi=ends[run].astype(np.int64))

    @property
    def count(self) -> int:
        """Number of sequences."""
        return int(np.count_nonzero(self.lo == np.arange(len(self.lo))))


@dataclasses.dataclass(frozen=True)
class SequenceMatches:
    """Result of :func:`sequence_search`, one entry per query.

    Attributes
    ----------
    match : numpy.ndarray
        ``int64 (Q,)`` best reference row, ``-1`` when not scored.
    score : numpy.ndarray
        ``float64 (Q,)`` sum of enhanced differences along the best trajectory; NaN when not
        scored.
    ratio : numpy.ndarray
        ``float64 (Q,)`` uniqueness ratio in ``[0, 1]``; NaN when not scored.
    """

    match: np.ndarray
    score: np.ndarray
    ratio: np.ndarray


@dataclasses.dataclass(frozen=True)
class MatchResult:
    """Result of :func:`match_sequences`.

    Attributes
    ----------
    match, score, ratio : numpy.ndarray
        ``(Q,)`` as in :class:`SequenceMatches`.
    single_frame_match : numpy.ndarray
        ``int64 (Q,)`` first argmin of each column of the raw ``D`` (every query).
    single_frame_ratio : numpy.ndarray
        ``float64 (Q,)`` uniqueness ratio of the single-frame match on raw ``D`` (same window
        and guards as ``ratio``).
    params : SeqSLAMParams
        The parameters used.
    D, D_hat : numpy.ndarray or None
        ``float32 (R, Q)`` difference and enhanced matrices when ``keep_matrices``; ``D_hat`` is
        ``D`` itself when the enhancement is off.
    sequence_top_k, single_frame_top_k : numpy.ndarray or None
        ``int64 (Q, K)`` the ``K`` best reference rows per query, best first (``-1``: none),
        by sequence score and by raw difference, when ``match_sequences(..., top_k=K)``; see
        the module docs.
    sequence_top_k_score, single_frame_top_k_difference : numpy.ndarray or None
        ``float64 (Q, K)`` their values: sequence scores (as ``score``) and raw differences
        (``D``); NaN where the row is ``-1``.
    seconds : dict
        Wall time of the two phases, summed over the chunks: ``difference`` (the difference
        rows) and ``search`` (enhancement, single-frame and sequence search, top K). Not
        compared by ``==``.
    """

    match: np.ndarray
    score: np.ndarray
    ratio: np.ndarray
    single_frame_match: np.ndarray
    single_frame_ratio: np.ndarray
    params: SeqSLAMParams
    D: np.ndarray | None = None
    D_hat: np.ndarray | None = None
    sequence_top_k: np.ndarray | None = None
    single_frame_top_k: np.ndarray | None = None
    sequence_top_k_score: np.ndarray | None = None
    single_frame_top_k_difference: np.ndarray | None = None
    seconds: dict = dataclasses.field(default_factory=dict, compare=False)

    @property
    def confidence_score(self) -> np.ndarray:
        """``float64 (Q,)``: ``ratio`` or ``score`` per ``params.score``; lower = more confident."""
        return self.ratio if self.params.score == "ratio" else self.score

    @property
    def n_scored(self) -> int:
        """Number of queries with a sequence match."""
        return int((self.match >= 0).sum())


def enhance_contrast(D: np.ndarray, *, r_window: int = 10,
                     reference_sequences=None) -> np.ndarray:
    """Local contrast enhancement of a difference matrix (paper eq. 14).

    Parameters
    ----------
    D : numpy.ndarray
        ``(R, Q)`` difference matrix (finite), taken as float32 like every difference matrix.
    r_window : int
        Window of ``r_window//2`` rows each side (inclusive), clipped at the ends; ``0`` returns
        ``D`` unchanged (as float32). ``1`` is rejected (one-row windows have no spread).
    reference_sequences : array-like, optional
        ``(R,)`` one sequence label per row; windows are clipped at sequence boundaries
        (:func:`match_sequences`).

    Returns
    -------
    numpy.ndarray
        ``float32 (R, Q)``: ``z - min(z)`` over the finite ``z``, so ``>= 0``; ``+inf`` where the
        window is constant. See the module docs.
    """
    D = _check_matrix(D, name="D", allow_inf=False)
    half = _enhancement_half(r_window)
    if half == 0:
        return D.astype(np.float32)
    blocks = SequenceBlocks.from_labels(reference_sequences, n=D.shape[0],
                                        name="reference_sequences")
    z = _enhanced_rows(np.ascontiguousarray(D.T, dtype=np.float32), half, blocks)
    m = _finite_min(z)
    if math.isfinite(m):
        z -= m
    return np.ascontiguousarray(z.T.astype(np.float32))


def sequence_search(D_hat: np.ndarray, *, ds: int = 10, v_min: float = 0.8, v_max: float = 1.1,
                    v_step: float = 0.1, r_window: int = 10) -> SequenceMatches:
    """Look-back sequence search (paper eqs. 15-16) over an enhanced difference matrix.

    Parameters
    ----------
    D_hat : numpy.ndarray
        ``(R, Q)`` enhanced (or raw) differences, ``>= 0``; ``+inf`` cells are excluded.
    ds, v_min, v_max, v_step : see :class:`~cmal_lcd.matching.SeqSLAMParams`
    r_window : int
        Uniqueness exclusion window: rows ``match - r_window//2 .. match + r_window//2``.

    Returns
    -------
    SequenceMatches
        ``match int64 (Q,)``, ``score float64 (Q,)``, ``ratio float64 (Q,)``; see the module docs.
    """
    params = SeqSLAMParams(ds=ds, v_min=v_min, v_max=v_max, v_step=v_step,
                           r_window=r_window, enhance=False, score="ratio")  # score: unused
    D_hat = _check_matrix(D_hat, name="D_hat", allow_inf=True)
    finite = D_hat[np.isfinite(D_hat)]
    if finite.size and finite.min() < 0:
        raise ValueError("D_hat has negative values; pass the output of enhance_contrast or a "
                         "raw difference matrix (the uniqueness ratio needs values >= 0)")
    rows = np.ascontiguousarray(D_hat.T)
    if rows.dtype not in (np.float32, np.float64):
        rows = rows.astype(np.float64)
    Q = rows.shape[0]
    match, best, second = _search(rows, first=params.ds, params=params)
    full = _pad_unscored(Q, params.ds, match, best, second)
    score, ratio = _scores_and_ratios(full[1], full[2], full[0], shift=0.0)
    return SequenceMatches(match=full[0], score=score, ratio=ratio)


def match_sequences(reference: np.ndarray, query: np.ndarray, *, metric: str,
                    params: SeqSLAMParams | None = None, keep_matrices: bool = False,
                    chunk_size: int | None = None, top_k: int = 0,
                    progress: Callable[[int], None] | None = None,
                    reference_sequences=None, query_sequences=None) -> MatchResult:
    """Full SeqSLAM matching: difference, enhancement, look-back search, streamed over queries.

    Parameters
    ----------
    reference : numpy.ndarray
        ``(R, F)`` reference features.
    query : numpy.ndarray
        ``(Q, F)`` query features, in time order.
    metric : {"sad", "sad_u8", "sqeuclidean", "sqeuclidean_f32"}
        Difference metric, see :func:`~cmal_lcd.matching.difference_matrix`.
    params : SeqSLAMParams, optional
        Defaults to Table I (``SeqSLAMParams.defaults()``).
    keep_matrices : bool
        Also return the full ``D`` and ``D_hat`` (``float32 (R, Q)`` each). Otherwise only one
        chunk of queries is held at a time.
    chunk_size : int, optional
        Queries per chunk (default: a float64 ``(chunk, R)`` array of about 32 MB). Results do
        not depend on it.
    top_k : int
        Also return the ``top_k`` best reference rows per query, by sequence score and by raw
        difference (``MatchResult.sequence_top_k`` / ``single_frame_top_k``, ``int64 (Q,
        top_k)``; for recall@K). ``0`` (default): not computed. Every other output is the same
        either way.
    progress : callable, optional
        Called with the number of queries of each chunk once it is matched (e.g.
        :meth:`cmal_lcd.progress.Progress.update`).
    reference_sequences, query_sequences : array-like, optional
        ``(R,)`` / ``(Q,)`` one sequence label per frame, when a side holds several sequences
        one after another (each a run of equal labels). Nothing crosses a reference sequence
        boundary: enhancement windows are clipped there as at the matrix ends, a trajectory
        must lie in its end row's sequence, and the uniqueness window is clipped to the
        match's sequence (rows of other sequences always compete). A query whose look-back
        (``ds`` earlier queries) reaches into an earlier query sequence is not scored, as the
        first ``ds`` queries are not. Default: one sequence each.

    Returns
    -------
    MatchResult
        See the module docs for every definition.
    """
    params = SeqSLAMParams.defaults() if params is None else params
    if not isinstance(params, SeqSLAMParams):
        raise ValueError(f"params must be a SeqSLAMParams, got {type(params).__name__}")
    op = DifferenceRows(reference, metric=metric)
    query = op.check_query(query)
    Q = query.shape[0]
    chunk_size = min(_checked_chunk_size(op.chunk_rows() if chunk_size is None else chunk_size), Q)
    top_k = _checked_top_k(top_k)
    blocks = SequenceBlocks.from_labels(reference_sequences, n=op.n_reference,
                                        name="reference_sequences")
    query_blocks = SequenceBlocks.from_labels(query_sequences, n=Q, name="query_sequences")
    run = _StreamedMatch.allocate(params, R=op.n_reference, Q=Q, chunk_size=chunk_size,
                                  top_k=top_k, keep_matrices=keep_matrices, blocks=blocks,
                                  query_blocks=query_blocks)
    seconds = {"difference": 0.0, "search": 0.0}
    for c0 in range(0, Q, chunk_size):
        c1 = min(Q, c0 + chunk_size)
        n_new = c1 - c0
        start = time.perf_counter()
        rows = op(query[c0:c1], out=run.d_buffer[:n_new])
        searched = time.perf_counter()
        run.match_chunk(rows, c0, c1)
        seconds["difference"] += searched - start
        seconds["search"] += time.perf_counter() - searched
        logger.debug("matched queries %d-%d of %d", c0, c1, Q)
        if progress is not None:
            progress(n_new)
    return dataclasses.replace(run.result(), seconds=seconds)


def single_frame_matches(D: np.ndarray, *, r_window: int = 10) -> tuple[np.ndarray, np.ndarray]:
    """Single-frame nearest neighbour on a difference matrix.

    Parameters
    ----------
    D : numpy.ndarray
        ``(R, Q)`` raw differences, ``>= 0``.
    r_window : int
        Uniqueness exclusion window, as in :func:`sequence_search`.

    Returns
    -------
    match : numpy.ndarray
        ``int64 (Q,)`` first argmin of each column.
    ratio : numpy.ndarray
        ``float64 (Q,)`` best over the best outside ``match +- r_window//2`` (guards as
        :func:`sequence_search`).
    """
    D = _check_matrix(D, name="D", allow_inf=False)
    if r_window < 0:
        raise ValueError(f"r_window must be >= 0, got {r_window!r}")
    rows = np.ascontiguousarray(D.T)
    if rows.dtype not in (np.float32, np.float64):
        rows = rows.astype(np.float64)
    Q = rows.shape[0]
    match = np.empty(Q, dtype=np.int64)
    best = np.empty(Q)
    second = np.empty(Q)
    blocks = SequenceBlocks.single(rows.shape[1])
    _kernels.best_rows(rows, int(r_window) // 2, blocks.lo, blocks.hi, match, best, second)
    _, ratio = _scores_and_ratios(best, second, match, shift=0.0)
    return match, ratio


# --------------------------------------------------------------------------------- helpers


def _checked_chunk_size(chunk_size) -> int:
    """``chunk_size`` if it is a positive integer, else ``ValueError``."""
    if isinstance(chunk_size, bool) or not isinstance(chunk_size, (int, np.integer)) \
            or chunk_size < 1:
        raise ValueError(f"chunk_size must be a positive integer, got {chunk_size!r}")
    return chunk_size


def _checked_top_k(top_k) -> int:
    """``top_k`` as an ``int`` if it is an integer ``>= 0``, else ``ValueError``."""
    if isinstance(top_k, bool) or not isinstance(top_k, (int, np.integer)) or top_k < 0:
        raise ValueError(f"top_k must be an integer >= 0, got {top_k!r}")
    return int(top_k)


@dataclasses.dataclass(eq=False)
class _StreamedMatch:
    """Buffers and per-query outputs of one :func:`match_sequences` run, filled chunk by chunk.

    Everything is query-major. ``search_buffer`` holds ``history`` (``<= ds``) rows of the
    previous chunks followed by the current chunk's rows: the unshifted float64 ``z`` when the
    enhancement is on (``minimum`` tracks its finite minimum), else the float32 differences.
    """

    params: SeqSLAMParams
    offsets: np.ndarray  # int64 (n_v, ds + 1) trajectory offsets
    top_k: int
    blocks: SequenceBlocks  # the reference sequences (R rows)
    query_blocks: SequenceBlocks  # the query sequences (Q queries)
    sf_match: np.ndarray  # int64 (Q,) single-frame best row
    sf_best: np.ndarray  # float64 (Q,) raw difference of that row
    sf_second: np.ndarray  # float64 (Q,) best outside its exclusion window
    match: np.ndarray  # int64 (Q,) sequence match, -1 until scored
    best: np.ndarray  # float64 (Q,) unshifted best sequence score, NaN until scored
    second: np.ndarray  # float64 (Q,) unshifted best outside the exclusion window
    D_full: np.ndarray | None  # float32 (Q, R) when keep_matrices
    Z_full: np.ndarray | None  # float64 (Q, R) unshifted z when keep_matrices and enhancing
    seq_top: np.ndarray | None  # int64 (Q, top_k) when top_k
    sf_top: np.ndarray | None  # int64 (Q, top_k) when top_k
    seq_top_value: np.ndarray | None  # float64 (Q, top_k) unshifted scores, NaN: none
    sf_top_value: np.ndarray | None  # float64 (Q, top_k) raw differences, NaN: none
    d_buffer: np.ndarray  # float32 (chunk_size, R) difference rows of one chunk
    search_buffer: np.ndarray  # float64 or float32 (ds + chunk_size, R)
    history: int = 0
    minimum: float = math.inf

    @classmethod
    def allocate(cls, params: SeqSLAMParams, *, R: int, Q: int, chunk_size: int, top_k: int,
                 keep_matrices: bool, blocks: SequenceBlocks,
                 query_blocks: SequenceBlocks) -> _StreamedMatch:
        """Buffers for ``Q`` queries against ``R`` reference rows, ``chunk_size <= Q`` at a time."""
        enhancing = params.enhancement_window // 2 > 0
        # a look-back as long as the queries scores none: neither its offsets nor more history
        # than there are queries are needed (ds = 10^9 would allocate gigabytes)
        ds = min(params.ds, Q)
        return cls(
            params=params, top_k=top_k, blocks=blocks, query_blocks=query_blocks,
            offsets=(trajectory_offsets(ds=ds, velocities=params.velocities()) if ds < Q
                     else np.zeros((0, 1), dtype=np.int64)),
            sf_match=np.empty(Q, dtype=np.int64), sf_best=np.empty(Q), sf_second=np.empty(Q),
            match=np.full(Q, -1, dtype=np.int64), best=np.full(Q, np.nan),
            second=np.full(Q, np.nan),
            D_full=np.empty((Q, R), dtype=np.float32) if keep_matrices else None,
            Z_full=np.empty((Q, R), dtype=np.float64) if keep_matrices and enhancing else None,
            seq_top=np.full((Q, top_k), -1, dtype=np.int64) if top_k else None,
            sf_top=np.full((Q, top_k), -1, dtype=np.int64) if top_k else None,
            seq_top_value=np.full((Q, top_k), np.nan) if top_k else None,
            sf_top_value=np.full((Q, top_k), np.nan) if top_k else None,
            d_buffer=np.empty((chunk_size, R), dtype=np.float32),
            search_buffer=np.empty((ds + chunk_size, R),
                                   dtype=np.float64 if enhancing else np.float32))

    @property
    def half_enh(self) -> int:
        """Enhancement half-window (``0``: no enhancement)."""
        return self.params.enhancement_window // 2

    @property
    def half_excl(self) -> int:
        """Uniqueness exclusion half-window."""
        return self.params.r_window // 2

    def match_chunk(self, d_rows: np.ndarray, c0: int, c1: int) -> None:
        """Match queries ``c0 .. c1 - 1`` from their ``float32 (c1 - c0, R)`` difference rows."""
        self._match_single_frames(d_rows, c0, c1)
        rows = self._append_search_rows(d_rows)
        if self.D_full is not None:
            self.D_full[c0:c1] = d_rows
            if self.Z_full is not None:
                self.Z_full[c0:c1] = rows
        n_rows = self.history + (c1 - c0)
        self._search_chunk(c0, c1, n_rows)
        self._keep_history(n_rows)

    def _match_single_frames(self, d_rows: np.ndarray, c0: int, c1: int) -> None:
        """Single-frame best rows (and top-k lists) of queries ``c0 .. c1 - 1``."""
        _kernels.best_rows(d_rows, self.half_excl, self.blocks.lo, self.blocks.hi,
                           self.sf_match[c0:c1], self.sf_best[c0:c1], self.sf_second[c0:c1])
        if self.top_k:
            self.sf_top[c0:c1], self.sf_top_value[c0:c1] = _top_k_rows(d_rows, self.top_k)

    def _append_search_rows(self, d_rows: np.ndarray) -> np.ndarray:
        """Write the chunk's unshifted ``z`` (or raw) rows after the history; returns the view."""
        rows = self.search_buffer[self.history:self.history + d_rows.shape[0]]
        if self.half_enh:
            _kernels.enhance_rows(d_rows, self.half_enh, self.blocks.lo, self.blocks.hi, rows)
            self.minimum = min(self.minimum, float(_kernels.finite_min(rows)))
        else:
            rows[:] = d_rows
        return rows

    def _search_chunk(self, c0: int, c1: int, n_rows: int) -> None:
        """Sequence search of the chunk's queries that have ``ds`` earlier queries."""
        start = c0 - self.history  # global query index of search_buffer row 0
        first = max(self.params.ds, c0) - start
        if first >= n_rows:
            return
        rows = self.search_buffer[:n_rows]
        lo = start + first
        self.match[lo:c1], self.best[lo:c1], self.second[lo:c1] = _search_rows(
            rows, first=first, offsets=self.offsets, half=self.half_excl, blocks=self.blocks)
        if self.top_k:
            # ranks of the unshifted scores = ranks of the shifted ones (one common shift)
            self.seq_top[lo:c1], self.seq_top_value[lo:c1] = _sequence_top_k(
                rows, first=first, offsets=self.offsets, k=self.top_k, blocks=self.blocks)
        self._unscore_across_query_sequences(lo, c1)

    def _unscore_across_query_sequences(self, lo: int, hi: int) -> None:
        """Queries ``lo .. hi - 1`` whose look-back reaches an earlier query sequence: unscored."""
        starts = self.query_blocks.lo[lo:hi]
        crossing = np.flatnonzero(np.arange(lo, hi) - self.params.ds < starts) + lo
        self.match[crossing] = -1
        self.best[crossing] = np.nan
        self.second[crossing] = np.nan
        if self.top_k:
            self.seq_top[crossing] = -1
            self.seq_top_value[crossing] = np.nan

    def _keep_history(self, n_rows: int) -> None:
        """Move the last ``min(ds, n_rows)`` search rows to the top of the search buffer."""
        self.history = min(self.params.ds, n_rows)
        self.search_buffer[:self.history] = \
            self.search_buffer[n_rows - self.history:n_rows].copy()

    def result(self) -> MatchResult:
        """Scores shifted by ``(ds + 1)`` times the enhancement minimum, ratios, matrices."""
        shift = self.minimum if (self.half_enh and math.isfinite(self.minimum)) else 0.0
        score, ratio = _scores_and_ratios(self.best, self.second, self.match,
                                          shift=(self.params.ds + 1) * shift)
        _, sf_ratio = _scores_and_ratios(self.sf_best, self.sf_second, self.sf_match, shift=0.0)
        D, D_hat = self._full_matrices(shift)
        return MatchResult(match=self.match, score=score, ratio=ratio,
                           single_frame_match=self.sf_match, single_frame_ratio=sf_ratio,
                           params=self.params, D=D, D_hat=D_hat, sequence_top_k=self.seq_top,
                           single_frame_top_k=self.sf_top,
                           sequence_top_k_score=None if self.seq_top_value is None
                           else np.maximum(self.seq_top_value - (self.params.ds + 1) * shift,
                                           0.0),  # as score; NaN stays NaN
                           single_frame_top_k_difference=self.sf_top_value)

    def _full_matrices(self, shift: float) -> tuple[np.ndarray | None, np.ndarray | None]:
        """``float32 (R, Q)`` ``D`` and ``D_hat`` (``z - shift``, or ``D`` when not enhanced)."""
        if self.D_full is None:
            return None, None
        D = np.ascontiguousarray(self.D_full.T)
        if self.Z_full is None:
            return D, D
        self.Z_full -= shift
        return D, np.ascontiguousarray(self.Z_full.T.astype(np.float32))


def _enhancement_half(r_window: int) -> int:
    return check_matching(r_window=r_window, enhance=True)["r_window"] // 2


def _enhanced_rows(rows: np.ndarray, half: int,
                   blocks: SequenceBlocks | None = None) -> np.ndarray:
    """``float64 (n, R)`` unshifted z-scores of query-major float32 rows (``+inf`` if constant),
    windows clipped at the ``blocks`` (default: one reference sequence)."""
    rows = np.ascontiguousarray(rows, dtype=np.float32)
    out = np.empty(rows.shape, dtype=np.float64)
    if rows.size:
        blocks = SequenceBlocks.single(rows.shape[1]) if blocks is None else blocks
        _kernels.enhance_rows(rows, half, blocks.lo, blocks.hi, out)
    return out


def _finite_min(x: np.ndarray) -> float:
    """Minimum of the finite values of a 2-D ``x`` (``+inf`` when there are none)."""
    return float(_kernels.finite_min(np.ascontiguousarray(x))) if x.size else math.inf


def _search_rows(rows: np.ndarray, *, first: int, offsets: np.ndarray, half: int,
                 blocks: SequenceBlocks | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Run the search kernel for local queries ``first..n-1`` of query-major ``rows``."""
    n = rows.shape[0] - first
    blocks = SequenceBlocks.single(rows.shape[1]) if blocks is None else blocks
    match = np.empty(n, dtype=np.int64)
    best = np.empty(n)
    second = np.empty(n)
    _kernels.search_rows(rows, first, offsets, half, blocks.lo, blocks.hi, match, best, second)
    return match, best, second


def _sequence_top_k(rows: np.ndarray, *, first: int, offsets: np.ndarray, k: int,
                    blocks: SequenceBlocks) -> tuple[np.ndarray, np.ndarray]:
    """Top-``k`` end rows by sequence score, and those scores, for local queries ``first..``
    of ``rows``.

    Parameters
    ----------
    rows : numpy.ndarray
        ``(n, R)`` query-major enhanced (or raw) differences; ``first >= ds``.
    offsets : numpy.ndarray
        ``int64 (n_v, ds + 1)`` trajectory offsets.
    blocks : SequenceBlocks
        The reference sequences.

    Returns
    -------
    rows, scores : numpy.ndarray
        ``int64 (n - first, k)`` and ``float64 (n - first, k)``, see :func:`_top_k_rows`.
    """
    out = np.full((rows.shape[0] - first, k), -1, dtype=np.int64)
    values = np.full(out.shape, np.nan)
    if out.size:
        _sequence_top_k_kernel(np.ascontiguousarray(rows), first,
                               np.ascontiguousarray(offsets, dtype=np.int64), blocks.lo, k, out,
                               values)
    return out, values


def _top_k_rows(values: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Indices of the ``k`` lowest values of every row, ascending, ties by the lower index,
    and those values.

    Parameters
    ----------
    values : numpy.ndarray
        ``(n, R)`` float, no NaN; ``+inf`` marks an invalid entry.

    Returns
    -------
    rows : numpy.ndarray
        ``int64 (n, k)``; ``-1`` for ``+inf`` entries and beyond ``R``.
    lowest : numpy.ndarray
        ``float64 (n, k)`` the values at ``rows``; NaN where ``rows`` is ``-1``.
    """
    out = np.full((values.shape[0], k), -1, dtype=np.int64)
    lowest = np.full(out.shape, np.nan)
    if out.size:
        _top_k_kernel(np.ascontiguousarray(values), k, out, lowest)
    return out, lowest


@njit(cache=True)
def _insert_top_k(value, index, buf, out, count, k):  # pragma: no cover - compiled
    """Insert ``(value, index)`` into the ascending ``buf``/``out`` of ``count`` entries.

    Stable: an equal value goes after those already there (they have lower indices), and a
    full buffer takes only a strictly lower value. Returns the new count.
    """
    if value == np.inf or (count == k and not value < buf[k - 1]):
        return count
    j = count if count < k else k - 1
    while j > 0 and buf[j - 1] > value:
        buf[j] = buf[j - 1]
        out[j] = out[j - 1]
        j -= 1
    buf[j] = value
    out[j] = index
    return count + 1 if count < k else k


@njit(parallel=True, cache=True)
def _top_k_kernel(values, k, out, out_values):  # pragma: no cover - compiled
    """Per row of ``values (n, R)``, the ``k`` best indices into ``out (n, k)`` (``-1`` filled)
    and their values into ``out_values (n, k)`` (NaN filled)."""
    n, R = values.shape
    for i in prange(n):
        row = values[i]
        buf = np.empty(k)
        count = 0
        for r in range(R):
            count = _insert_top_k(row[r], r, buf, out[i], count, k)
        for j in range(count):
            out_values[i, j] = buf[j]


@njit(parallel=True, cache=True)
def _sequence_top_k_kernel(rows, first, offsets, block_lo, k, out,
                           out_values):  # pragma: no cover
    """Top-``k`` end rows by sequence score for queries ``first..`` of ``rows (n, R)``, their
    scores into ``out_values``.

    The per-row scores are the search kernel's (``_kernels.search_rows``): float64 sums in
    ascending time ``j = ds .. 0``, best over velocities, ``+inf`` when invalid (also when the
    trajectory starts before its end row's sequence, ``block_lo``); so entry 0 is its ``match``.
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
                # 0-based view loop (as the search kernel) so that LLVM vectorises it
                o = offsets[v, j]
                col = rows[t - j, o_max - o:R - o]
                for s in range(m_valid):
                    acc_v[s] += col[s]
            lo_v = block_lo[o_max:]
            for s in range(m_valid):
                if acc_v[s] < best_v[s] and lo_v[s] <= s:
                    best_v[s] = acc_v[s]
        buf = np.empty(k)
        count = 0
        dest = out[t - first]
        for s in range(R):
            count = _insert_top_k(per_row[s], s, buf, dest, count, k)
        for j in range(count):
            out_values[t - first, j] = buf[j]


def _search(rows: np.ndarray, *, first: int, params: SeqSLAMParams):
    if first >= rows.shape[0]:  # no query has ds earlier ones: nothing to allocate
        empty = np.empty(0)
        return np.empty(0, dtype=np.int64), empty, empty
    offsets = trajectory_offsets(ds=params.ds, velocities=trajectory_velocities(
        v_min=params.v_min, v_max=params.v_max, v_step=params.v_step))
    return _search_rows(rows, first=first, offsets=offsets, half=params.r_window // 2)


def _pad_unscored(Q: int, first: int, match, best, second):
    """Place per-query results of queries ``first..Q-1`` into ``(Q,)`` arrays (``-1`` / NaN)."""
    m = np.full(Q, -1, dtype=np.int64)
    b = np.full(Q, np.nan)
    s = np.full(Q, np.nan)
    m[first:] = match
    b[first:] = best
    s[first:] = second
    return m, b, s


def _scores_and_ratios(best: np.ndarray, second: np.ndarray, match: np.ndarray, *,
                       shift: float) -> tuple[np.ndarray, np.ndarray]:
    """Scores ``best - shift`` and uniqueness ratios, NaN where ``match < 0``.

    ``shift`` is ``(ds + 1) * min(z)`` for the streamed search on unshifted enhanced values; a
    result that rounding pushed below 0 is clamped to 0. Ratio guards: ``second = inf -> 0``,
    ``best == second == 0 -> 1``.
    """
    scored = match >= 0
    score = np.full(match.shape, np.nan)
    ratio = np.full(match.shape, np.nan)
    b = np.maximum(best[scored] - shift, 0.0)
    s = np.maximum(second[scored] - shift, 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.where(np.isinf(s), 0.0, np.where(s == 0.0, 1.0, b / np.where(s == 0.0, 1.0, s)))
    score[scored] = b
    ratio[scored] = r
    return score, ratio


def _check_matrix(D: np.ndarray, *, name: str, allow_inf: bool) -> np.ndarray:
    D = np.asarray(D)
    if D.ndim != 2:
        raise ValueError(f"{name} must be a 2-D (R, Q) array, got shape {D.shape}")
    if D.shape[0] < 1 or D.shape[1] < 1:
        raise ValueError(f"{name} must not be empty, got shape {D.shape}")
    if not (np.issubdtype(D.dtype, np.floating) or np.issubdtype(D.dtype, np.integer)):
        raise ValueError(f"{name} must be real-valued, got dtype {D.dtype}")
    if np.issubdtype(D.dtype, np.floating):
        if np.isnan(D).any():
            raise ValueError(f"{name} contains NaN")
        if allow_inf:
            if np.isneginf(D).any():
                raise ValueError(f"{name} contains -inf")
        elif not np.isfinite(D).all():
            raise ValueError(f"{name} contains infinite values")
    return D
