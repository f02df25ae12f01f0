"""Difficulty of the weather world, measured with SAD + SeqSLAM (the paper's baseline).

For every route and every ordered pair of conditions ``(a, b)`` (reference ``a``, query ``b``),
the cross-weather pair matches the dataset's drive under ``b`` against the drive under ``a``.
Its same-weather baseline has the same geometry with the weather held fixed: a second,
independently wandering drive under ``a`` over ``b``'s window, matched against the drive under
``a``. The world is in a useful range when, on every route, the cross-weather single-frame SAD
recall@1 (mean over the ordered pairs) lies within ``[0.2, 0.8]`` and the same-weather mean is
clearly higher.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

#: Acceptance band of the cross-weather single-frame recall@1 of a route (mean over pairs).
CROSS_RANGE = (0.2, 0.8)
#: "Clearly easier": same-weather mean recall@1 exceeds the cross-weather mean by this much.
SAME_MARGIN = 0.1
#: The calibrated quantity: single-frame recall@1 over the queries whose place is in the
#: reference (``cmal_lcd.evaluation``'s ``single_frame_recall_at_1`` divides by every scored
#: query, negatives included, so its ceiling is the share of positives).
SF_KEY = "sf_recall_at_1"
#: Metrics reported per pair (besides :data:`SF_KEY`).
METRIC_KEYS = ("single_frame_recall_at_1", "recall_at_100p", "auc_pr", "auc_roc", "n_query",
               "n_positive")


@dataclass(frozen=True)
class SadMatching:
    """What SAD matching needs from the ``matching`` config node."""

    params: Any  # cmal_lcd.matching.SeqSLAMParams
    d_thresh: int
    pose_tolerance: float
    sad: dict

    @classmethod
    def from_config(cls, matching: Mapping[str, Any]) -> "SadMatching":
        from cmal_lcd.matching import SeqSLAMParams

        for key in ("d_thresh", "pose_tolerance", "sad"):
            if key not in matching:
                raise ValueError(f"matching.{key}: required by the world calibration")
        return cls(params=SeqSLAMParams.from_config(matching), d_thresh=matching["d_thresh"],
                   pose_tolerance=matching["pose_tolerance"], sad=dict(matching["sad"]))


def sad_codes(images: np.ndarray, matching: SadMatching) -> np.ndarray:
    """Patch-normalised SAD thumbnails of ``images`` (uint8 (N, H, W, 3)) -> (N, h * w)."""
    from cmal_lcd.matching import sad_thumbnails, thumbnail_options

    return sad_thumbnails(images, **thumbnail_options(matching.sad))


def pair_difficulty(reference_codes: np.ndarray, reference_xy: np.ndarray,
                    query_codes: np.ndarray, query_xy: np.ndarray, *,
                    matching: SadMatching) -> dict[str, float]:
    """SeqSLAM over SAD codes of one reference/query drive pair, ground truth from poses.

    Parameters
    ----------
    reference_codes, query_codes : ndarray (R, F), (Q, F)
        SAD thumbnails (:func:`sad_codes`).
    reference_xy, query_xy : ndarray, float (R, 2), (Q, 2)
        Camera positions, metres.
    matching : SadMatching

    Returns
    -------
    dict
        :data:`SF_KEY` (share of the queries with a true place whose single-frame nearest
        neighbour lies within ``d_thresh`` frames of it) and :data:`METRIC_KEYS` (``auc_roc``
        is NaN when no scored query is wrong).
    """
    import warnings

    from cmal_lcd.evaluation import ground_truth_from_poses, loop_closure_metrics
    from cmal_lcd.matching import match_sequences, sad_metric

    truth = ground_truth_from_poses(reference_xy, query_xy, max_distance=matching.pose_tolerance)
    result = match_sequences(reference_codes, query_codes, metric=sad_metric(matching.sad),
                             params=matching.params)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # an undefined ROC AUC (no wrong match) is reported NaN
        metrics = loop_closure_metrics(result.match, result.confidence_score, truth,
                                       d_thresh=matching.d_thresh,
                                       single_frame_match=result.single_frame_match)
    positive = truth >= 0
    near = np.abs(result.single_frame_match - truth) <= matching.d_thresh
    out = {SF_KEY: float(near[positive].mean())}
    out.update({key: metrics[key] for key in METRIC_KEYS})
    return out


def summarise(table: dict[str, dict[str, dict[str, dict[str, float]]]]) -> dict[str, Any]:
    """Per-route means and the acceptance checks.

    Parameters
    ----------
    table : dict
        ``{route: {pair: {"cross": metrics, "same": metrics}}}``.

    Returns
    -------
    dict
        ``{route: {cross_recall_at_1, same_recall_at_1, cross_in_range, same_clearly_easier,
        ok}}`` plus ``ok`` (every route ok) and the criteria.
    """
    summary: dict[str, Any] = {"criteria": {"cross_recall_at_1_range": list(CROSS_RANGE),
                                            "same_minus_cross_at_least": SAME_MARGIN}}
    all_ok = True
    for route, pairs in table.items():
        cross = float(np.mean([p["cross"][SF_KEY] for p in pairs.values()]))
        same = float(np.mean([p["same"][SF_KEY] for p in pairs.values()]))
        low, high = CROSS_RANGE
        in_range = low <= cross <= high
        easier = same - cross >= SAME_MARGIN
        summary[route] = {"cross_recall_at_1": cross, "same_recall_at_1": same,
                          "cross_in_range": bool(in_range), "same_clearly_easier": bool(easier),
                          "ok": bool(in_range and easier)}
        all_ok = all_ok and in_range and easier
    summary["ok"] = bool(all_ok)
    return summary


def _fmt(value: float) -> str:
    return "n/a" if value is None or not np.isfinite(value) else f"{value:.3f}"


def difficulty_markdown(table: dict, summary: dict) -> str:
    """The calibration as a Markdown report (one table per route)."""
    low, high = CROSS_RANGE
    lines = [
        "# Difficulty of the weather world (SAD + SeqSLAM)",
        "",
        "Reference drive under the first condition, query drive under the second; the "
        "same-weather baseline repeats the reference condition over the query's window (a second, "
        "independently wandering drive), so only the weather differs between the two columns. "
        "`sf R@1`: single-frame nearest-neighbour recall@1 over the queries whose place is in "
        "the reference; `R@100P`: SeqSLAM recall at 100% precision; tolerance `d_thresh` "
        "frames, ground truth from poses.",
        "",
        f"Acceptance, per route: the mean cross-weather `sf R@1` over the pairs in "
        f"[{low}, {high}] and the mean same-weather `sf R@1` at least {SAME_MARGIN} above it.",
        "",
    ]
    for route, pairs in table.items():
        s = summary[route]
        lines += [f"## {route}", "",
                  "| pair | cross sf R@1 | cross R@100P | cross AUC-PR | same sf R@1 | "
                  "same R@100P | same AUC-PR | positives / queries |",
                  "|---|---|---|---|---|---|---|---|"]
        for pair, m in pairs.items():
            c, w = m["cross"], m["same"]
            lines.append(f"| {pair} | {_fmt(c[SF_KEY])} | "
                         f"{_fmt(c['recall_at_100p'])} | {_fmt(c['auc_pr'])} | "
                         f"{_fmt(w[SF_KEY])} | {_fmt(w['recall_at_100p'])} | "
                         f"{_fmt(w['auc_pr'])} | {c['n_positive']} / {c['n_query']} |")
        lines += ["", f"Mean sf R@1: cross {s['cross_recall_at_1']:.3f}, same "
                      f"{s['same_recall_at_1']:.3f}; cross in range: {s['cross_in_range']}; "
                      f"same clearly easier: {s['same_clearly_easier']}.", ""]
    lines.append(f"Overall: {'within' if summary['ok'] else 'OUTSIDE'} the useful range.")
    return "\n".join(lines) + "\n"
