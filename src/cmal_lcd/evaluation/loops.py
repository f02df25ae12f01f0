"""Loop closure evaluation within one traversal: ground truth from poses, the usual metrics.

Definitions (on top of :mod:`cmal_lcd.evaluation.metrics`, whose functions compute every
number):

- a **revisit** of frame ``q`` is an earlier frame outside the exclusion zone
  (``r < n_allowed[q]``) within ``pose_tolerance`` metres of it; a frame with none is a
  **negative** (any loop closure it reports is a false positive);
- a scored frame's match is **correct** when it lies within ``d_thresh`` frames of *any* of its
  revisits (:func:`~cmal_lcd.data.ground_truth.revisit_nearest_to`), so on a route driven
  several times every earlier pass counts;
- PR curve, ``auc_pr``, ``auc_roc``, ``recall_at_100p`` and ``recall_at_1`` are
  :func:`~cmal_lcd.evaluation.loop_closure_metrics` of the sequence matches with that truth;
  recall is over the scored frames that have a revisit (``n_positive``);
  ``single_frame_recall_at_1`` uses the revisit nearest to the single-frame match.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cmal_lcd.data.ground_truth import loop_ground_truth_from_poses, revisit_nearest_to
from cmal_lcd.evaluation.metrics import (correct_matches, loop_closure_metrics,
                                         precision_recall_curve)
from cmal_lcd.matching.loops import LoopResult


@dataclass(frozen=True)
class LoopEvaluation:
    """Metrics of one single-traversal run.

    Attributes
    ----------
    metrics : dict
        :data:`~cmal_lcd.evaluation.METRIC_KEYS` plus ``n_revisit`` (frames with a revisit).
    precision, recall, thresholds : numpy.ndarray
        ``float64 (T,)`` the exact PR curve.
    truth : numpy.ndarray
        ``int64 (N,)`` the spatially nearest revisit per frame, ``-1`` for a negative.
    correct : numpy.ndarray
        ``bool (N,)`` whether each frame's sequence match is correct (``False`` if unscored).
    """

    metrics: dict
    precision: np.ndarray
    recall: np.ndarray
    thresholds: np.ndarray
    truth: np.ndarray
    correct: np.ndarray


def evaluate_loops(result: LoopResult, xy: np.ndarray, *, pose_tolerance: float,
                   d_thresh: int) -> LoopEvaluation:
    """Score a :func:`~cmal_lcd.matching.loops.match_loops` result against poses.

    Parameters
    ----------
    result : LoopResult
        Matches of the ``N`` frames, with their ``n_allowed`` exclusion zone.
    xy : numpy.ndarray
        ``(N, 2)`` positions in metres.
    pose_tolerance : float
        Metres: how close an earlier frame must be to count as a revisit.
    d_thresh : int
        Frames: how close a match must be to a revisit to be correct.

    Returns
    -------
    LoopEvaluation

    Raises
    ------
    ValueError
        When no frame is scored, or no scored frame has a revisit (recall undefined).
    """
    truth = loop_ground_truth_from_poses(xy, pose_tolerance=pose_tolerance,
                                         n_allowed=result.n_allowed)
    near_match = revisit_nearest_to(result.match, xy, pose_tolerance=pose_tolerance,
                                    n_allowed=result.n_allowed)
    near_single = revisit_nearest_to(result.single_frame_match, xy,
                                     pose_tolerance=pose_tolerance, n_allowed=result.n_allowed)
    try:
        metrics = loop_closure_metrics(result.match, result.confidence_score, near_match,
                                       d_thresh=d_thresh)
    except ValueError as err:
        raise ValueError(f"poses: {err} (pose_tolerance {pose_tolerance} m, "
                         f"{int((truth >= 0).sum())} of {truth.size} frames have a revisit)"
                         ) from err
    scored = result.match >= 0
    single_correct = correct_matches(result.single_frame_match, near_single, d_thresh=d_thresh)
    metrics["single_frame_recall_at_1"] = float(single_correct[scored].sum() / scored.sum())
    metrics["n_revisit"] = int((truth >= 0).sum())
    correct = correct_matches(result.match, near_match, d_thresh=d_thresh)
    precision, recall, thresholds = precision_recall_curve(
        result.confidence_score[scored], correct[scored], n_positive=metrics["n_positive"])
    return LoopEvaluation(metrics=metrics, precision=precision, recall=recall,
                          thresholds=thresholds, truth=truth, correct=correct)
