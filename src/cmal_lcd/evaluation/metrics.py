"""Loop-closure metrics: exact PR curve, ROC AUC, recall at 100% precision, recall@K.

Definitions (paper eqs. 17-18), stated once
--------------------------------------------
Every **scored** query (``match >= 0``; queries without enough history are left out) has a
confidence (the uniqueness ratio or the sequence score, **lower = more confident**) and is

- **correct** when its place is in the reference (``truth >= 0``) and
  ``|match - truth| <= d_thresh`` frames (Table I: 20, ``matching.d_thresh`` of
  ``conf/matching/seqslam.yaml``).

At a threshold ``t`` a query is **accepted** (declared a loop closure) when
``confidence <= t``. Then

- TP = accepted and correct;
- FP = accepted and not correct (wrong place, or a place absent from the reference);
- FN = a query whose place is in the reference (``truth >= 0``) and that is not a TP (rejected,
  or accepted at the wrong place);
- TN = rejected and its place is absent from the reference.

``precision = TP / (TP + FP)``; ``recall = TP / n_positive`` with ``n_positive`` = the number of
scored queries with ``truth >= 0`` (= TP + FN). A query whose best match is wrong can never
become a TP, so recall may stay below 1 (the usual place-recognition convention).

- **PR curve**: one point per distinct confidence value (every distinct score is a threshold,
  ascending), no artificial end points (:func:`precision_recall_curve`).
- ``auc_pr``: area under that exact curve, step-wise: ``sum_k (R_k - R_{k-1}) P_k`` with
  ``R_0 = 0`` (scikit-learn's ``average_precision_score`` with label ``correct`` and score
  ``-confidence``, times ``n_correct / n_positive`` because our recall is over ``n_positive``).
- ``auc_roc``: ROC of the binary label ``correct`` against the score ``-confidence`` over the
  scored queries (scikit-learn's ``roc_auc_score`` semantics: TPR = accepted correct / all
  correct, FPR = accepted incorrect / all incorrect, trapezoidal area, ties handled exactly).
  Undefined when all or none of the scored queries are correct: then NaN, with a logged warning.
- ``recall_at_100p``: the largest recall at a threshold where precision is exactly 1 (no FP);
  0 when the most confident query (or tie group) holds a wrong match.
- ``recall_at_1``: the share of scored queries whose sequence match is correct
  (``n_correct / n_scored``).
- ``single_frame_recall_at_1``: the same share for the single-frame nearest neighbour of the
  raw difference matrix, over the same scored queries (NaN when it is not given).
- ``recall_at_K`` (K in :data:`RECALL_KS` beyond 1: 5, 10, 20), the place-recognition
  recall@K: the share of scored queries with a correct reference row (within ``d_thresh`` of
  the true place) among their ``K`` best, ranked by sequence score; ``single_frame_recall_at_K``
  ranks by the raw difference. Given only when the ranked lists are (``top_k`` arguments of
  :func:`loop_closure_metrics`, from ``match_sequences(..., top_k=K)``); the lists start with
  the match, so recall@1 from them equals ``recall_at_1`` and recall@K never decreases in K.

Ground truth as sets (the field's files)
----------------------------------------
Every function taking ``truth`` also takes a
:class:`~cmal_lcd.data.ground_truth.ReferenceSets` (VPR-Bench, VPR_Tutorial,
VPR-methods-evaluation, MSLS ground truth; ``docs/ground_truth.md``). Then a match is
**correct** when it is one of the query's right reference rows (the file's own tolerance;
``d_thresh`` plays no part), a query's place is in the reference when it has a right row, and a
query whose match is an *ignored* row (VPR_Tutorial's ``GTsoft`` without ``GThard``) is neither
right nor wrong: it is left out of the scored queries. In ranked lists an ignored row is not a
hit and takes no rank (the rows after it move up).

Edge cases: no scored query, or no scored query with ``truth >= 0`` (recall undefined), raise a
``ValueError`` naming the input.
"""

from __future__ import annotations

import logging

import numpy as np

from cmal_lcd.data.ground_truth import ReferenceSets

logger = logging.getLogger(__name__)

#: Keys of :func:`loop_closure_metrics`.
METRIC_KEYS = ("auc_pr", "auc_roc", "recall_at_100p", "recall_at_1", "single_frame_recall_at_1",
               "n_query", "n_scored", "n_positive")

#: The K of recall@K (place-recognition convention).
RECALL_KS = (1, 5, 10, 20)

#: Keys :func:`loop_closure_metrics` adds when given ranked lists (recall@1 is always there).
RECALL_AT_K_KEYS = tuple(f"{prefix}recall_at_{k}" for prefix in ("", "single_frame_")
                         for k in RECALL_KS if k != 1)


def correct_matches(match: np.ndarray, truth: np.ndarray | ReferenceSets, *,
                    d_thresh: int) -> np.ndarray:
    """Which matches are correct: ``match >= 0``, ``truth >= 0``, ``|match - truth| <= d_thresh``
    (with :class:`ReferenceSets`: ``match`` is a right row of its query).

    Parameters
    ----------
    match : numpy.ndarray
        ``int (Q,)`` matched reference indices (``-1``: none).
    truth : numpy.ndarray or ReferenceSets
        ``int (Q,)`` true reference indices (``-1``: none), or the right rows per query.
    d_thresh : int
        Tolerance in frames, ``>= 0`` (unused with :class:`ReferenceSets`).

    Returns
    -------
    numpy.ndarray
        ``bool (Q,)``.
    """
    match = _int_vector(match, name="match")
    if not np.isfinite(d_thresh) or d_thresh < 0:
        raise ValueError(f"d_thresh must be >= 0, got {d_thresh!r}")
    if isinstance(truth, ReferenceSets):
        return truth.is_right(_query_shaped(match, truth))
    truth = _int_vector(truth, name="truth")
    if match.shape != truth.shape:
        raise ValueError(f"match and truth must have the same shape, got {match.shape} and "
                         f"{truth.shape}")
    return (match >= 0) & (truth >= 0) & (np.abs(match - truth) <= d_thresh)


def ignored_matches(match: np.ndarray, truth: np.ndarray | ReferenceSets) -> np.ndarray:
    """``bool (Q,)``: matches that are neither right nor wrong (a :class:`ReferenceSets`'s
    ignored rows, e.g. VPR_Tutorial's ``GTsoft`` without ``GThard``; none for index truth)."""
    match = _int_vector(match, name="match")
    if isinstance(truth, ReferenceSets):
        return truth.is_ignored(_query_shaped(match, truth))
    return np.zeros(match.shape, dtype=bool)


def place_in_reference(truth: np.ndarray | ReferenceSets) -> np.ndarray:
    """``bool (Q,)``: the query's place is in the reference (``truth >= 0``, or a right row)."""
    if isinstance(truth, ReferenceSets):
        return truth.has_place()
    return _int_vector(truth, name="truth") >= 0


def _query_shaped(rows: np.ndarray, truth: ReferenceSets) -> np.ndarray:
    if rows.shape[0] != truth.n_query:
        raise ValueError(f"match has {rows.shape[0]} queries but the ground truth "
                         f"({truth.source or 'reference sets'}) has {truth.n_query}")
    return rows


def recall_at_k(top_k: np.ndarray, truth: np.ndarray, *, d_thresh: int,
                ks=RECALL_KS, queries: np.ndarray | None = None) -> dict[int, float]:
    """Recall@K: share of queries with a correct reference row among their ``K`` best.

    Parameters
    ----------
    top_k : numpy.ndarray
        ``int (Q, K_max)`` reference rows per query, best first (``-1``: none), as
        ``MatchResult.sequence_top_k`` / ``single_frame_top_k``.
    truth : numpy.ndarray or ReferenceSets
        ``int (Q,)`` true reference index per query, ``-1`` when the place is absent (such a
        query is never correct); or the right rows per query.
    d_thresh : int
        A row within ``d_thresh`` frames of the true place is correct (index truth only).
    ks : sequence of int
        The K values, each in ``1 .. K_max``.
    queries : numpy.ndarray, optional
        ``bool (Q,)`` the queries counted (the denominator); default: all.

    Returns
    -------
    dict
        ``{K: float}``.

    Raises
    ------
    ValueError
        On shape mismatches, a K outside ``1 .. K_max``, or no query counted.
    """
    top_k = np.asarray(top_k)
    n_query = truth.n_query if isinstance(truth, ReferenceSets) else _int_vector(
        truth, name="truth").size
    if top_k.ndim != 2 or top_k.shape[0] != n_query \
            or not np.issubdtype(top_k.dtype, np.integer):
        raise ValueError(f"top_k must be an integer array of shape ({n_query}, K), got "
                         f"{top_k.dtype} {top_k.shape}")
    bad = [k for k in ks if isinstance(k, bool) or not 1 <= int(k) <= top_k.shape[1]]
    if bad:
        raise ValueError(f"ks must lie in 1..{top_k.shape[1]} (the columns of top_k), got {bad}")
    counted = np.ones(n_query, dtype=bool) if queries is None else np.asarray(queries, bool)
    if counted.shape != (n_query,):
        raise ValueError(f"queries must have shape ({n_query},), got {counted.shape}")
    n = int(counted.sum())
    if n == 0:
        raise ValueError("queries: no query to count")
    rows = top_k.astype(np.int64)
    if isinstance(truth, ReferenceSets):
        hit = truth.is_right(rows)
        # an ignored row takes no rank: the rows after it move up (as VPR_Tutorial's recallAtK
        # did before 2025 by pushing GTsoft-only similarities to the bottom; docs/ground_truth.md)
        rank = np.cumsum(~truth.is_ignored(rows), axis=1) - 1
    else:
        truth = _int_vector(truth, name="truth")
        hit = (rows >= 0) & (truth[:, None] >= 0) & (np.abs(rows - truth[:, None]) <= d_thresh)
        rank = np.broadcast_to(np.arange(rows.shape[1]), rows.shape)
    # first_hit[q]: rank of the best correct row, top_k.shape[1] when none
    first_hit = np.where(hit.any(axis=1), rank[np.arange(rows.shape[0]), hit.argmax(axis=1)],
                         rows.shape[1])
    return {int(k): float(np.sum(counted & (first_hit < int(k))) / n) for k in ks}


def precision_recall_curve(confidence: np.ndarray, correct: np.ndarray, *,
                           n_positive: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact precision-recall curve: every distinct confidence value is a threshold.

    Parameters
    ----------
    confidence : numpy.ndarray
        ``float (n,)`` finite confidences of the scored queries, lower = more confident.
    correct : numpy.ndarray
        ``bool (n,)`` whether each query's match is correct.
    n_positive : int
        Recall denominator: scored queries whose place is in the reference
        (``>= correct.sum()``, ``>= 1``).

    Returns
    -------
    precision, recall : numpy.ndarray
        ``float64 (T,)`` at each threshold.
    thresholds : numpy.ndarray
        ``float64 (T,)`` the distinct confidences, ascending (a query is accepted when its
        confidence is ``<= threshold``).
    """
    confidence, correct = _check_scores(confidence, correct)
    n_correct = int(correct.sum())
    if isinstance(n_positive, bool) or not isinstance(n_positive, (int, np.integer)) \
            or n_positive < max(1, n_correct):
        raise ValueError(f"n_positive must be an integer >= max(1, number of correct) = "
                         f"{max(1, n_correct)}, got {n_positive!r}")
    thresholds, tp, accepted = _cumulative_counts(confidence, correct)
    precision = tp / accepted
    recall = tp / float(n_positive)
    return precision, recall, thresholds


def roc_curve(confidence: np.ndarray, correct: np.ndarray) -> tuple[np.ndarray, np.ndarray,
                                                                   np.ndarray]:
    """Exact ROC curve of the label ``correct`` against the score ``-confidence``.

    Returns
    -------
    fpr, tpr : numpy.ndarray
        ``float64 (T + 1,)`` starting at ``(0, 0)`` (nothing accepted); NaN-free only when both
        classes are present (else the undefined rate is NaN).
    thresholds : numpy.ndarray
        ``float64 (T + 1,)``: ``-inf`` then the distinct confidences ascending.
    """
    confidence, correct = _check_scores(confidence, correct)
    thresholds, tp, accepted = _cumulative_counts(confidence, correct)
    fp = accepted - tp
    n_true, n_false = int(correct.sum()), int((~correct).sum())
    with np.errstate(invalid="ignore", divide="ignore"):
        tpr = np.concatenate([[0.0], tp]) / n_true if n_true else np.full(tp.size + 1, np.nan)
        fpr = np.concatenate([[0.0], fp]) / n_false if n_false else np.full(tp.size + 1, np.nan)
    return fpr, tpr, np.concatenate([[-np.inf], thresholds])


def loop_closure_metrics(match: np.ndarray, confidence: np.ndarray, truth: np.ndarray, *,
                         d_thresh: int,
                         single_frame_match: np.ndarray | None = None,
                         top_k: np.ndarray | None = None,
                         single_frame_top_k: np.ndarray | None = None) -> dict:
    """All loop-closure metrics of one reference/query pair (definitions in the module docs).

    Parameters
    ----------
    match : numpy.ndarray
        ``int (Q,)`` sequence match per query, ``-1`` when not scored.
    confidence : numpy.ndarray
        ``float (Q,)`` lower = more confident; must be finite where ``match >= 0`` (NaN allowed
        elsewhere).
    truth : numpy.ndarray or ReferenceSets
        ``int (Q,)`` true reference index per query, ``-1`` when the place is absent; or the
        right (and ignored) rows per query (module docs).
    d_thresh : int
        Tolerance in frames (``matching.d_thresh``; Table I: 20; index truth only).
    single_frame_match : numpy.ndarray, optional
        ``int (Q,)`` single-frame nearest neighbour per query.
    top_k, single_frame_top_k : numpy.ndarray, optional
        ``int (Q, K)`` with ``K >= 20``: the best reference rows per query by sequence score
        and by raw difference (``MatchResult.sequence_top_k`` / ``single_frame_top_k``).

    Returns
    -------
    dict
        ``auc_pr, auc_roc, recall_at_100p, recall_at_1, single_frame_recall_at_1`` (floats) and
        ``n_query, n_scored, n_positive`` (ints); with ``top_k`` also ``recall_at_{5,10,20}``
        and with ``single_frame_top_k`` ``single_frame_recall_at_{5,10,20}``, over the scored
        queries (:data:`RECALL_AT_K_KEYS`).

    Raises
    ------
    ValueError
        On shape mismatches, a non-finite confidence of a scored query, no scored query, or no
        scored query whose place is in the reference.
    """
    match, confidence, truth = _checked_queries(match, confidence, truth)
    scored, correct, n_positive = scored_and_correct(match, confidence, truth, d_thresh=d_thresh)
    n_scored = int(scored.sum())
    correct = correct[scored]
    conf = confidence[scored]
    auc_pr, recall_at_100p = _precision_recall_summary(conf, correct, n_positive=n_positive)
    out = {
        "auc_pr": auc_pr,
        "auc_roc": _auc_roc(conf, correct),
        "recall_at_100p": recall_at_100p,
        "recall_at_1": float(correct.sum() / n_scored),
        "single_frame_recall_at_1": _single_frame_recall(single_frame_match, truth, scored,
                                                         d_thresh=d_thresh),
        "n_query": int(match.size),
        "n_scored": n_scored,
        "n_positive": n_positive,
    }
    out.update(_ranked_recalls(truth, scored, d_thresh=d_thresh, top_k=top_k,
                               single_frame_top_k=single_frame_top_k))
    return out


def scored_and_correct(match: np.ndarray, confidence: np.ndarray,
                       truth: np.ndarray | ReferenceSets, *,
                       d_thresh: int) -> tuple[np.ndarray, np.ndarray, int]:
    """The scored queries, which are correct, and ``n_positive`` (module docs).

    Returns
    -------
    scored, correct : numpy.ndarray
        ``bool (Q,)``: ``match >= 0`` and not an ignored row; correct (and scored).
    n_positive : int
        Scored queries whose place is in the reference (at least one, else ``ValueError``).
    """
    match, confidence, truth = _checked_queries(match, confidence, truth)
    scored = _scored_queries(match, confidence) & ~ignored_matches(match, truth)
    if not scored.any():
        raise ValueError("match: every scored query matched a reference row the ground truth "
                         "ignores (neither right nor wrong)")
    correct = correct_matches(match, truth, d_thresh=d_thresh) & scored
    return scored, correct, _positive_count(place_in_reference(truth)[scored])


def _checked_queries(match: np.ndarray, confidence: np.ndarray,
                     truth: np.ndarray | ReferenceSets):
    """``int64 (Q,)`` match, ``float64 (Q,)`` confidence, ``int64 (Q,)`` truth (or the
    :class:`ReferenceSets` as given), shapes checked."""
    match = _int_vector(match, name="match")
    n_truth = truth.n_query if isinstance(truth, ReferenceSets) else None
    if n_truth is None:
        truth = _int_vector(truth, name="truth")
        n_truth = truth.size
    confidence = np.asarray(confidence, dtype=np.float64)
    if confidence.shape != match.shape or (n_truth,) != match.shape:
        raise ValueError(f"match, confidence and truth must have the same shape (Q,), got "
                         f"{match.shape}, {confidence.shape}, ({n_truth},)")
    return match, confidence, truth


def _scored_queries(match: np.ndarray, confidence: np.ndarray) -> np.ndarray:
    """``bool (Q,)`` the scored queries (``match >= 0``): at least one, all confidences finite."""
    scored = match >= 0
    if not scored.any():
        raise ValueError("match: no scored query (every match is -1): a sequence needs at least "
                         "ds + 1 query frames, and a query whose every trajectory crosses a "
                         "constant stretch of the difference matrix (e.g. identical codes) "
                         "has no valid trajectory")
    if not np.isfinite(confidence[scored]).all():
        raise ValueError("confidence must be finite for every scored query (match >= 0)")
    return scored


def _positive_count(scored_has_place: np.ndarray) -> int:
    """``n_positive``: scored queries whose place is in the reference (at least one)."""
    n_positive = int(scored_has_place.sum())
    if n_positive == 0:
        raise ValueError("truth: no scored query has its place in the reference (truth >= 0), "
                         "so recall is undefined")
    return n_positive


def _precision_recall_summary(conf: np.ndarray, correct: np.ndarray, *,
                              n_positive: int) -> tuple[float, float]:
    """``auc_pr`` and ``recall_at_100p`` from the exact PR curve of ``(n,)`` scored queries."""
    precision, recall, _ = precision_recall_curve(conf, correct, n_positive=n_positive)
    auc_pr = float(np.sum(np.diff(np.concatenate([[0.0], recall])) * precision))
    # precision is 1 on a prefix of the thresholds: once an FP is accepted it stays accepted
    perfect = precision == 1.0
    recall_at_100p = float(recall[perfect].max()) if perfect.any() else 0.0
    return auc_pr, recall_at_100p


def _auc_roc(conf: np.ndarray, correct: np.ndarray) -> float:
    """ROC AUC of ``(n,)`` scored queries; NaN (with a warning) when only one class is present."""
    if correct.all() or not correct.any():
        logger.warning("auc_roc is undefined (NaN): %s of the %d scored queries are correct",
                       "all" if correct.all() else "none", correct.size)
        return float("nan")
    fpr, tpr, _ = roc_curve(conf, correct)
    return float(np.trapezoid(tpr, fpr))


def _single_frame_recall(single_frame_match: np.ndarray | None, truth: np.ndarray,
                         scored: np.ndarray, *, d_thresh: int) -> float:
    """Share of the scored queries whose ``(Q,)`` single-frame match is correct (NaN if none)."""
    if single_frame_match is None:
        return float("nan")
    sf = _int_vector(single_frame_match, name="single_frame_match")
    if sf.shape != scored.shape:
        raise ValueError(f"single_frame_match must have shape {scored.shape}, got {sf.shape}")
    n_scored = int(scored.sum())
    return float(correct_matches(sf, truth, d_thresh=d_thresh)[scored].sum() / n_scored)


def _ranked_recalls(truth: np.ndarray, scored: np.ndarray, *, d_thresh: int,
                    top_k: np.ndarray | None, single_frame_top_k: np.ndarray | None) -> dict:
    """``{prefix}recall_at_{5,10,20}`` over the scored queries, for each ``(Q, K)`` list given."""
    out = {}
    for prefix, ranked in (("", top_k), ("single_frame_", single_frame_top_k)):
        if ranked is None:
            continue
        recalls = recall_at_k(ranked, truth, d_thresh=d_thresh, queries=scored)
        out.update({f"{prefix}recall_at_{k}": value for k, value in recalls.items() if k != 1})
    return out


def _cumulative_counts(confidence: np.ndarray, correct: np.ndarray):
    """Distinct thresholds (ascending) with cumulative TP and accepted counts at each."""
    order = np.argsort(confidence, kind="stable")
    conf = confidence[order]
    hits = correct[order].astype(np.float64)
    last = np.flatnonzero(np.concatenate([conf[1:] != conf[:-1], [True]]))
    tp = np.cumsum(hits)[last]
    accepted = (last + 1).astype(np.float64)
    return conf[last], tp, accepted


def _check_scores(confidence: np.ndarray, correct: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    confidence = np.asarray(confidence, dtype=np.float64)
    correct = np.asarray(correct)
    if confidence.ndim != 1 or correct.shape != confidence.shape:
        raise ValueError(f"confidence and correct must be 1-D of the same length, got "
                         f"{confidence.shape} and {correct.shape}")
    if confidence.size == 0:
        raise ValueError("confidence is empty")
    if correct.dtype != np.bool_:
        raise ValueError(f"correct must be a bool array, got dtype {correct.dtype}")
    if not np.isfinite(confidence).all():
        raise ValueError("confidence contains NaN or infinite values")
    return confidence, correct


def _int_vector(x: np.ndarray, *, name: str) -> np.ndarray:
    x = np.asarray(x)
    if x.ndim != 1:
        raise ValueError(f"{name} must be a 1-D array, got shape {x.shape}")
    if not np.issubdtype(x.dtype, np.integer):
        raise ValueError(f"{name} must hold integers, got dtype {x.dtype}")
    return x.astype(np.int64)
