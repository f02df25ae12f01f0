"""Loop closure evaluation of one feature method on one reference/query drive pair.

Joins the matching library (SeqSLAM) and the metrics: codes of two drives in, the Table II
metrics and the PR curve out. Pure functions; the ``evaluate`` stage does the file I/O.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from cmal_lcd.evaluation import loop_closure_metrics, precision_recall_curve
from cmal_lcd.matching import MatchResult, SeqSLAMParams, match_sequences

#: Variants evaluated for every method: the paper's setting and the no-enhancement ablation.
VARIANTS = ("enhanced", "plain")


@dataclass(frozen=True)
class PairEvaluation:
    """Result of matching one query drive against one reference drive.

    Attributes
    ----------
    metrics : dict
        ``auc_pr, auc_roc, recall_at_100p, recall_at_1, single_frame_recall_at_1`` and counts.
    precision, recall, thresholds : ndarray
        The exact PR curve (one point per distinct confidence score).
    result : MatchResult
        SeqSLAM output, with the difference matrices when asked for.
    truth : ndarray, int64 (Q,)
        True reference index per query, ``-1`` where the place is absent from the reference.
    """

    metrics: dict
    precision: np.ndarray
    recall: np.ndarray
    thresholds: np.ndarray
    result: MatchResult
    truth: np.ndarray


def params_for_variant(params: SeqSLAMParams, variant: str) -> SeqSLAMParams:
    """SeqSLAM parameters of a variant: ``enhanced`` (as configured) or ``plain`` (no eq. 14)."""
    if variant == "enhanced":
        return params
    if variant == "plain":
        return dataclasses.replace(params, enhance=False)
    raise ValueError(f"variant: expected one of {VARIANTS}, got {variant!r}")


def evaluate_pair(reference: np.ndarray, query: np.ndarray, truth: np.ndarray, *, metric: str,
                  params: SeqSLAMParams, d_thresh: int,
                  keep_matrices: bool = False) -> PairEvaluation:
    """Match ``query`` against ``reference`` with SeqSLAM and compute the loop closure metrics.

    Parameters
    ----------
    reference : ndarray (R, F)
        Per-frame features of the reference drive.
    query : ndarray (Q, F)
        Per-frame features of the query drive.
    truth : ndarray, int (Q,)
        Index of each query's true place in the reference, ``-1`` when absent.
    metric : {"sad", "sqeuclidean"}
        Frame difference (SAD for thumbnails, squared Euclidean for codes, paper eq. 13).
    params : SeqSLAMParams
        Sequence matching parameters (paper Table I).
    d_thresh : int
        A match within ``d_thresh`` frames of the true place is correct (Table I).
    """
    truth = np.asarray(truth, dtype=np.int64)
    if truth.shape != (len(query),):
        raise ValueError(f"truth: expected shape ({len(query)},), got {truth.shape}")
    result = match_sequences(reference, query, metric=metric, params=params,
                             keep_matrices=keep_matrices)
    metrics = loop_closure_metrics(result.match, result.confidence_score, truth,
                                   d_thresh=d_thresh,
                                   single_frame_match=result.single_frame_match)
    scored = result.match >= 0
    correct = scored & (truth >= 0) & (np.abs(result.match - truth) <= d_thresh)
    n_positive = int(np.sum(scored & (truth >= 0)))
    if scored.any() and n_positive > 0:
        precision, recall, thresholds = precision_recall_curve(
            result.confidence_score[scored], correct[scored], n_positive=n_positive)
    else:
        precision = recall = thresholds = np.zeros(0)
    return PairEvaluation(metrics=metrics, precision=np.asarray(precision),
                          recall=np.asarray(recall), thresholds=np.asarray(thresholds),
                          result=result, truth=truth)
