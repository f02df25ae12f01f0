"""Loop closure evaluation of one feature method on one reference/query drive pair.

Joins the matching library (SeqSLAM) and the metrics: codes of two drives in, the Table II
metrics and the PR curve out. Pure functions; the ``evaluate`` stage does the file I/O.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from collections.abc import Mapping
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # annotations only: `cmal-lcd match` with SAD imports no pandas
    import pandas as pd

from cmal_lcd.evaluation import (RECALL_KS, ground_truth_from_correspondence,
                                 ground_truth_from_poses, loop_closure_metrics,
                                 precision_recall_curve)
from cmal_lcd.data.ground_truth import ReferenceSets
from cmal_lcd.evaluation.metrics import scored_and_correct
from cmal_lcd.evaluation.protocol import MatchingProtocol
from cmal_lcd.matching import MatchResult, SeqSLAMParams, match_sequences
from cmal_lcd.matching.normalise import normalise_pair
from cmal_lcd.progress import LOG_INTERVAL_S, Progress

logger = logging.getLogger(__name__)

#: Variants evaluated for every method: ``selected`` (the protocol chosen on the validation
#: route; the main tables) and ``paper`` (raw codes, eq. 14 with Table I's window; ablation).
VARIANTS = ("selected", "paper")
#: The ``selected`` run scored at ``matching.d_thresh_strict`` (when set), in ``metrics.json``
#: beside the variants, with its tolerance as ``d_thresh``.
STRICT = "strict"


def ground_truth_for_pair(reference: pd.DataFrame, query: pd.DataFrame, *,
                          kind: str | Mapping[tuple[str, str], ReferenceSets],
                          pose_tolerance: float) -> np.ndarray | ReferenceSets:
    """The ground truth of a drive pair: ``int64 (Q,)`` true reference index of every query
    frame (``-1`` = absent), or the pair's :class:`ReferenceSets`.

    Parameters
    ----------
    reference, query : DataFrame
        Frame tables of the two drives (columns ``drive``, and ``x, y`` when
        ``kind == "poses"``).
    kind : {"poses", "index"} or mapping
        From poses (nearest reference pose within ``pose_tolerance`` metres), by frame index,
        or the sets of every ``(reference drive, query drive)`` (a ground-truth file's, stored
        by the dataset stage: :func:`dataset_ground_truth`).
    """
    if isinstance(kind, Mapping):
        key = (str(reference["drive"].iloc[0]), str(query["drive"].iloc[0]))
        if key not in kind:
            raise ValueError(f"ground truth: the dataset holds none for drives {key[0]!r} -> "
                             f"{key[1]!r}")
        sets = kind[key]
        if (sets.n_reference, sets.n_query) != (len(reference), len(query)):
            raise ValueError(f"ground truth of {key[0]!r} -> {key[1]!r}: {sets.n_reference} x "
                             f"{sets.n_query} frames, the drives {len(reference)} x "
                             f"{len(query)}")
        return sets
    if kind == "poses":
        return ground_truth_from_poses(reference[["x", "y"]].to_numpy(float),
                                       query[["x", "y"]].to_numpy(float),
                                       max_distance=pose_tolerance)
    if kind == "index":
        return ground_truth_from_correspondence(len(reference), len(query))
    raise ValueError(f"ground_truth: expected 'poses' or 'index', got {kind!r}")


def dataset_ground_truth(meta: Mapping) -> str | dict[tuple[str, str], ReferenceSets]:
    """The ``kind`` of :func:`ground_truth_for_pair` for a dataset's ``dataset.json``: its
    ``ground_truth`` (``"poses"`` when absent), or, when the dataset stored sets per drive pair
    (``ground_truth_sets``: a ground-truth file or UTM names, ``data.kind: folders``), those."""
    stored = meta.get("ground_truth_sets")
    if not stored:
        return meta.get("ground_truth", "poses")
    described = meta.get("ground_truth_source") or {}
    return {(entry["reference"], entry["query"]): ReferenceSets.from_arrays(
                entry, source=described.get("source", ""),
                tolerance=described.get("tolerance", ""))
            for entry in stored}


def dataset_sequences(meta: Mapping) -> dict[str, np.ndarray]:
    """``int64 (n,)`` sequence labels of every drive of ``dataset.json`` that holds several
    sequences (``drives[].sequence_starts``: a Mapillary SLS side), by drive name; drives of
    one sequence are absent."""
    labels = {}
    for drive in meta.get("drives", []):
        starts = drive.get("sequence_starts")
        if starts is not None:
            new = np.zeros(int(drive["frames"]), dtype=np.int64)
            new[np.asarray(starts, dtype=np.int64)] = 1
            labels[drive["name"]] = np.cumsum(new) - 1
    return labels


@dataclass(frozen=True)
class PairEvaluation:
    """Result of matching one query drive against one reference drive.

    Attributes
    ----------
    metrics : dict
        ``auc_pr, auc_roc, recall_at_100p, recall_at_1, single_frame_recall_at_1``,
        recall@K for K = 5, 10, 20 (``recall_at_K``, ``single_frame_recall_at_K``) and counts.
    precision, recall, thresholds : ndarray
        The exact PR curve (one point per distinct confidence score).
    result : MatchResult
        SeqSLAM output, with the difference matrices when asked for.
    truth : ndarray or ReferenceSets
        ``int64 (Q,)`` true reference index per query, ``-1`` where the place is absent from
        the reference; or the right reference rows per query (a ground-truth file).
    """

    metrics: dict
    precision: np.ndarray
    recall: np.ndarray
    thresholds: np.ndarray
    result: MatchResult
    truth: np.ndarray | ReferenceSets


def evaluate_pair(reference: np.ndarray, query: np.ndarray, truth: np.ndarray, *, metric: str,
                  params: SeqSLAMParams, d_thresh: int, keep_matrices: bool = False,
                  protocol: MatchingProtocol | None = None,
                  train_means: np.ndarray | None = None, reference_sequences=None,
                  query_sequences=None) -> PairEvaluation:
    """Match ``query`` against ``reference`` with SeqSLAM and compute the loop closure metrics.

    Parameters
    ----------
    reference : ndarray (R, F)
        Per-frame features of the reference drive.
    query : ndarray (Q, F)
        Per-frame features of the query drive.
    truth : ndarray or ReferenceSets
        ``int (Q,)`` index of each query's true place in the reference, ``-1`` when absent;
        or the right reference rows per query (:mod:`cmal_lcd.data.gt_files`).
    metric : {"sad", "sad_u8", "sqeuclidean", "sqeuclidean_f32"}
        Frame difference (SAD for thumbnails, squared Euclidean for codes, paper eq. 13).
    params : SeqSLAMParams
        Sequence matching parameters (paper Table I).
    d_thresh : int
        A match within ``d_thresh`` frames of the true place is correct (Table I).
    protocol : MatchingProtocol, optional
        Code normalisation and enhancement; replaces ``params.enhance`` and
        ``params.r_window``. None: ``params`` as given, codes as given.
    train_means : ndarray (K, F), optional
        Training-set mean code per condition (``centre="condition"``).
    reference_sequences, query_sequences : array-like, optional
        ``(R,)`` / ``(Q,)`` sequence labels when a side holds several sequences (Mapillary
        SLS); see :func:`~cmal_lcd.matching.match_sequences`.
    """
    if isinstance(truth, ReferenceSets):
        if (truth.n_reference, truth.n_query) != (len(reference), len(query)):
            raise ValueError(f"ground truth {truth.source}: it is {truth.n_reference} "
                             f"reference x {truth.n_query} query frames, the features "
                             f"{len(reference)} x {len(query)}")
    else:
        truth = np.asarray(truth, dtype=np.int64)
        if truth.shape != (len(query),):
            raise ValueError(f"truth: expected shape ({len(query)},), got {truth.shape}")
    if protocol is not None:
        reference, query = normalise_pair(reference, query, protocol.normalisation,
                                          train_means=train_means)
        params = protocol.seqslam(params)
    result = match_sequences(reference, query, metric=metric, params=params,
                             keep_matrices=keep_matrices, top_k=max(RECALL_KS),
                             reference_sequences=reference_sequences,
                             query_sequences=query_sequences)
    metrics = match_metrics(result, truth, d_thresh=d_thresh)
    # loop_closure_metrics has raised unless some query is scored and has its place
    scored, correct, n_positive = scored_and_correct(result.match, result.confidence_score,
                                                     truth, d_thresh=d_thresh)
    precision, recall, thresholds = precision_recall_curve(
        result.confidence_score[scored], correct[scored], n_positive=n_positive)
    return PairEvaluation(metrics=metrics, precision=np.asarray(precision),
                          recall=np.asarray(recall), thresholds=np.asarray(thresholds),
                          result=result, truth=truth)


def match_metrics(result: MatchResult, truth: np.ndarray | ReferenceSets, *,
                  d_thresh: int) -> dict:
    """The loop-closure metrics of one SeqSLAM run at tolerance ``d_thresh`` (frames): the
    sequence match, its recall@K and the single-frame recall@K
    (:func:`~cmal_lcd.evaluation.metrics.loop_closure_metrics`). Scoring the same run at a
    second tolerance (``matching.d_thresh_strict``) needs no new matching."""
    return loop_closure_metrics(result.match, result.confidence_score, truth,
                                d_thresh=d_thresh, single_frame_match=result.single_frame_match,
                                top_k=result.sequence_top_k,
                                single_frame_top_k=result.single_frame_top_k)


def single_frame_metrics(result: MatchResult, truth: np.ndarray | ReferenceSets, *,
                         d_thresh: int) -> dict:
    """The loop-closure metrics of the single-frame nearest neighbour, over every query.

    The same definitions as the sequence metrics (:mod:`cmal_lcd.evaluation.metrics`), with the
    single-frame match (first argmin of each column of the raw ``D``) for the match, its
    uniqueness ratio (``MatchResult.single_frame_ratio``, lower = more confident) for the
    confidence and the raw-difference ranking for recall@K. Queries whose ratio is not finite
    are not scored. Keys: those of :func:`loop_closure_metrics` but
    ``single_frame_recall_at_1`` (``recall_at_1`` is it, over these queries).
    """
    ratio = np.asarray(result.single_frame_ratio, dtype=np.float64)
    match = np.where(np.isfinite(ratio), result.single_frame_match, -1)
    metrics = loop_closure_metrics(match, ratio, truth, d_thresh=d_thresh,
                                   top_k=result.single_frame_top_k)
    del metrics["single_frame_recall_at_1"]
    return metrics


def drive_rows(frames: pd.DataFrame, drive: str) -> np.ndarray:
    """Positions (into ``frames``, whose index is ``0..n-1``) of the frames of ``drive``."""
    return np.flatnonzero(frames["drive"].to_numpy() == drive)


def evaluate_drive_pairs(codes: np.ndarray, frames: pd.DataFrame, pairs, *, metric: str,
                         params: SeqSLAMParams, d_thresh: int, ground_truth: str,
                         pose_tolerance: float, protocol: MatchingProtocol | None = None,
                         train_means: np.ndarray | None = None, keep_matrices: bool = False,
                         progress: str | None = "evaluate",
                         sequences: Mapping[str, np.ndarray] | None = None):
    """Evaluate every ``[route, reference_drive, query_drive, pair]`` of one split.

    Parameters
    ----------
    codes : ndarray (N, F)
        One row per frame of ``frames`` (same order).
    frames : DataFrame
        The split's frame table, index ``0..N-1``.
    pairs : sequence of [route, reference_drive, query_drive, pair]
    ground_truth : {"poses", "index"}
    progress : str, optional
        Label of the progress over pairs (:class:`cmal_lcd.progress.Progress`: a bar on a
        terminal after 2 s, a log line every 30 s otherwise); None: none.
    sequences : mapping, optional
        Sequence labels of the drives that hold several sequences (:func:`dataset_sequences`);
        sequence matching never crosses their boundaries.

    Yields
    ------
    route, pair : str
    evaluation : PairEvaluation

    Raises
    ------
    ValueError
        When a pair names a drive with no frames (naming the pair and the drives).
    """
    pairs = list(pairs)
    with Progress(len(pairs), desc=progress or "", unit="pair", logger=logger,
                  terminal=None if progress else False,
                  interval=LOG_INTERVAL_S if progress else math.inf) as bar:
        for route, ref_drive, query_drive, pair in pairs:
            ref_rows = drive_rows(frames, ref_drive)
            query_rows = drive_rows(frames, query_drive)
            if len(ref_rows) == 0 or len(query_rows) == 0:
                raise ValueError(f"pair {pair} of {route} names a drive with no frames "
                                 f"({ref_drive!r}: {len(ref_rows)}, {query_drive!r}: "
                                 f"{len(query_rows)})")
            truth = ground_truth_for_pair(frames.iloc[ref_rows], frames.iloc[query_rows],
                                          kind=ground_truth, pose_tolerance=pose_tolerance)
            try:
                evaluation = evaluate_pair(codes[ref_rows], codes[query_rows], truth,
                                           metric=metric, params=params, d_thresh=d_thresh,
                                           keep_matrices=keep_matrices, protocol=protocol,
                                           train_means=train_means,
                                           reference_sequences=(sequences or {}).get(ref_drive),
                                           query_sequences=(sequences or {}).get(query_drive))
            except ValueError as err:
                raise ValueError(f"{route} {pair}: {err}") from err
            yield route, pair, evaluation
            bar.update(1)
