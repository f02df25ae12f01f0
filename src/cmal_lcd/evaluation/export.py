"""What downstream tools need from a matched pair, per query (``docs/ground_truth.md``).

:func:`per_query_columns` turns a :class:`~cmal_lcd.evaluation.loop_closure.PairEvaluation`
into plain columns: the sequence match and its confidence, the single-frame nearest neighbour
and its ratio, and each one's verdict under the ground truth; :func:`matches_csv` is their
``matches.csv`` text. :func:`candidate_arrays` gives the ranked candidates (top K by sequence
score and by raw difference), the arrays of ``candidates.npz``. No I/O here: ``cmal-lcd match``
and the ``evaluate`` stage write both files.
"""

from __future__ import annotations

import csv
import io
from typing import TYPE_CHECKING

import numpy as np

from cmal_lcd.data.ground_truth import ReferenceSets
from cmal_lcd.evaluation.metrics import correct_matches, ignored_matches

if TYPE_CHECKING:
    from cmal_lcd.evaluation.loop_closure import PairEvaluation

#: Verdicts of a match under the ground truth.
RIGHT, WRONG, IGNORED, UNSCORED = "right", "wrong", "ignored", "unscored"

#: Columns of :func:`per_query_columns`, in order.
MATCH_COLUMNS = ("query", "query_frame", "match", "reference_frame", "score", "ratio",
                 "confidence", "verdict", "single_frame_match", "single_frame_reference_frame",
                 "single_frame_ratio", "single_frame_verdict", "true_reference")


def verdicts(match: np.ndarray, confidence: np.ndarray, truth: np.ndarray | ReferenceSets, *,
             d_thresh: int) -> np.ndarray:
    """``str (Q,)``: :data:`RIGHT`, :data:`WRONG`, :data:`IGNORED` (an entry the ground truth
    leaves out) or :data:`UNSCORED` (no match, or a non-finite confidence)."""
    match = np.asarray(match, dtype=np.int64)
    scored = (match >= 0) & np.isfinite(np.asarray(confidence, dtype=np.float64))
    right = correct_matches(match, truth, d_thresh=d_thresh)
    ignored = ignored_matches(match, truth)
    out = np.full(match.shape, WRONG, dtype=object)
    out[right] = RIGHT
    out[ignored] = IGNORED
    out[~scored] = UNSCORED
    return out.astype(str)


def true_reference(evaluation: PairEvaluation) -> np.ndarray:
    """``int64 (Q,)`` the true reference row per query (index truth), or with a ground-truth
    file the right row nearest the sequence match; ``-1`` when the query has none."""
    truth = evaluation.truth
    if isinstance(truth, ReferenceSets):
        return truth.nearest_right(evaluation.result.match)
    return np.asarray(truth, dtype=np.int64)


def per_query_columns(evaluation: PairEvaluation, *, d_thresh: int, reference_names: list[str],
                      query_names: list[str]) -> dict[str, np.ndarray]:
    """:data:`MATCH_COLUMNS` as arrays of length ``Q``; frame names are ``""`` where the row
    is ``-1``."""
    result = evaluation.result
    names = np.asarray(list(reference_names) + [""], dtype=str)  # index -1 -> ""
    return {
        "query": np.arange(len(query_names)),
        "query_frame": np.asarray(query_names, dtype=str),
        "match": result.match,
        "reference_frame": names[result.match],
        "score": result.score,
        "ratio": result.ratio,
        "confidence": result.confidence_score,
        "verdict": verdicts(result.match, result.confidence_score, evaluation.truth,
                            d_thresh=d_thresh),
        "single_frame_match": result.single_frame_match,
        "single_frame_reference_frame": names[result.single_frame_match],
        "single_frame_ratio": result.single_frame_ratio,
        "single_frame_verdict": verdicts(result.single_frame_match, result.single_frame_ratio,
                                         evaluation.truth, d_thresh=d_thresh),
        "true_reference": true_reference(evaluation),
    }


def matches_csv(evaluation: PairEvaluation, *, d_thresh: int, reference_names: list[str],
                query_names: list[str]) -> str:
    """``matches.csv``: a header of :data:`MATCH_COLUMNS`, then one row per query
    (:func:`per_query_columns`); floats at ``repr`` precision, empty where NaN."""
    columns = per_query_columns(evaluation, d_thresh=d_thresh,
                                reference_names=reference_names, query_names=query_names)
    text = io.StringIO()
    writer = csv.writer(text, lineterminator="\n")
    writer.writerow(MATCH_COLUMNS)
    writer.writerows(zip(*(_csv_values(columns[name]) for name in MATCH_COLUMNS)))
    return text.getvalue()


def _csv_values(values) -> list:
    """Plain Python values of a column: floats with ``repr`` precision, NaN as empty."""
    values = np.asarray(values)
    if values.dtype.kind == "f":
        return ["" if not np.isfinite(v) else repr(float(v)) for v in values]
    return values.tolist()


def candidate_arrays(evaluation: PairEvaluation, *, reference_names: list[str],
                     query_names: list[str]) -> dict[str, np.ndarray]:
    """The arrays of ``candidates.npz``: ``sequence_top_k`` and ``single_frame_top_k``
    (``int64 (Q, K)``, best first, ``-1``: none) with their values ``sequence_top_k_score`` and
    ``single_frame_top_k_difference`` (``float64 (Q, K)``, NaN: none) when the search ranked
    them; ``match``, ``score``, ``confidence``, ``single_frame_match`` and
    ``single_frame_ratio`` (``(Q,)``); ``reference_frames`` and ``query_frames`` (names)."""
    result = evaluation.result
    out = {"reference_frames": np.asarray(reference_names, dtype=str),
           "query_frames": np.asarray(query_names, dtype=str),
           "match": result.match, "score": result.score,
           "confidence": result.confidence_score,
           "single_frame_match": result.single_frame_match,
           "single_frame_ratio": result.single_frame_ratio}
    for key in ("sequence_top_k", "single_frame_top_k", "sequence_top_k_score",
                "single_frame_top_k_difference"):
        value = getattr(result, key)
        if value is not None:
            out[key] = value
    return out
