"""Evaluation: loop-closure metrics (and, in ``invariance``, code statistics).

Pure functions, no I/O (the commands that write an output folder, ``cmal-lcd match`` and
``loops``, are :mod:`cmal_lcd.workflows`). The TP/FP/FN/TN definitions and every metric are
written once in
:mod:`cmal_lcd.evaluation.metrics`; the ground-truth conventions, part of a dataset, in
:mod:`cmal_lcd.data.ground_truth` (re-exported here). ``cmal_lcd.evaluation.invariance`` (code-invariance
statistics) is a separate module, imported on its own.
"""

from cmal_lcd.data.ground_truth import (
    ground_truth_from_correspondence,
    ground_truth_from_poses,
)
from cmal_lcd.evaluation.metrics import (
    METRIC_KEYS,
    RECALL_AT_K_KEYS,
    RECALL_KS,
    correct_matches,
    loop_closure_metrics,
    precision_recall_curve,
    recall_at_k,
    roc_curve,
)

__all__ = [
    "METRIC_KEYS",
    "RECALL_AT_K_KEYS",
    "RECALL_KS",
    "correct_matches",
    "ground_truth_from_correspondence",
    "ground_truth_from_poses",
    "loop_closure_metrics",
    "precision_recall_curve",
    "recall_at_k",
    "roc_curve",
]
