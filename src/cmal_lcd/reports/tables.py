"""The report's tables, built as pandas DataFrames of raw values.

Each builder takes the pipeline's nested metrics ``{route: {pair: {method: {metric: value}}}}``
or per-method info dicts (:func:`recall_at_100p_table`, :func:`auc_table`,
:func:`recall_at_k_table`, :func:`ablation_table`, :func:`inference_table`,
:func:`invariance_table`, :func:`protocol_table`, :func:`layer_choice_table`,
:func:`validation_curve_table`) and returns floats (strings for text columns). Rows are indexed
by one or more levels (e.g. method label, source); columns by ``(route, pair)`` or plain names.
:mod:`cmal_lcd.reports.render` renders them (Markdown, CSV, LaTeX); the two are kept apart so
each is testable.

A metric is a fraction in ``[0, 1]``; a missing value is NaN (``null`` in JSON).
"""

from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import numpy as np
import pandas as pd

from cmal_lcd.reports import paper
from cmal_lcd.reports.render import MISSING


#: The five loop-closure metrics reported per route, pair and method (required).
METRIC_KEYS = ("auc_pr", "auc_roc", "recall_at_100p", "recall_at_1", "single_frame_recall_at_1")
#: The K of recall@K (the place-recognition convention; K = 1 is in :data:`METRIC_KEYS`).
RECALL_KS = (1, 5, 10, 20)
#: recall@K beyond K = 1, sequence and single-frame: NaN when an evaluation file predates them.
OPTIONAL_METRIC_KEYS = tuple(f"{prefix}recall_at_{k}" for prefix in ("", "single_frame_")
                             for k in RECALL_KS if k != 1)
#: Display names of the metrics.
METRIC_LABELS = {
    "auc_pr": "AUC-PR",
    "auc_roc": "AUC-ROC",
    "recall_at_100p": "recall@100%P",
    "recall_at_1": "recall@1",
    "single_frame_recall_at_1": "single-frame recall@1",
    **{f"recall_at_{k}": f"recall@{k}" for k in RECALL_KS if k != 1},
    **{f"single_frame_recall_at_{k}": f"single-frame recall@{k}" for k in RECALL_KS if k != 1},
}
#: The compact per-method summary (``reports/summary/<method>.json``; its R@100P is the DVC
#: metric, ``reports/summary.json``): short key -> metric. Short keys keep ``dvc metrics show -R
#: reports/summary`` within a 100-column terminal.
SUMMARY_KEYS = {"R@100P": "recall_at_100p", "AUC-PR": "auc_pr", "AUC-ROC": "auc_roc",
                "R@1": "recall_at_1", "R@5": "recall_at_5",
                "SF-R@1": "single_frame_recall_at_1"}
#: Names of the evaluation variants in tables.
VARIANT_LABELS = {"selected": "protocol chosen on validation",
                  "paper": "paper protocol (raw codes, eq. 14)"}
#: ``source`` level of Table II rows measured by this pipeline.
THIS_RUN = "this run"

Nested = Mapping[str, Mapping[str, Mapping[str, Mapping[str, float]]]]


# ---------------------------------------------------------------------------------------------
# Reshaping the evaluation files
# ---------------------------------------------------------------------------------------------

def as_float(value: object) -> float:
    """A metric value as float; ``None`` (JSON ``null``) becomes NaN."""
    return math.nan if value is None else float(value)


def metrics_by_route_pair_method(evaluations: Mapping[str, Mapping], *, methods: Sequence[str],
                                 variant: str,
                                 pair_order: Sequence[tuple[str, str]] = ()) -> dict:
    """Regroup per-method evaluation files into the report's nesting.

    Parameters
    ----------
    evaluations : mapping
        ``{method: {route: {pair: {variant: {metric: value}}}}}`` (the contents of
        ``data/evaluation/<method>/metrics.json``).
    methods : sequence of str
        Methods to keep, in table order.
    variant : str
        ``"selected"`` (each method's protocol chosen on validation drives) or ``"paper"``
        (raw codes with eq. 14, the paper's setting, an ablation).
    pair_order : sequence of (route, pair), optional
        Preferred order of routes and pairs (e.g. the dataset's); pairs not listed follow in the
        order the files give them.

    Returns
    -------
    dict
        ``{route: {pair: {method: {metric: float}}}}`` with the keys of :data:`METRIC_KEYS`
        and those of :data:`OPTIONAL_METRIC_KEYS` the file has (NaN where it holds ``null``;
        :func:`metric_value` reads an absent key as NaN).

    Raises
    ------
    ValueError
        Naming ``evaluations`` and the method, route, pair or variant that is missing.
    """
    order = _route_pair_order(evaluations, methods=methods, pair_order=pair_order)
    nested: dict = {}
    for route, pair in order:
        for method in methods:
            try:
                values = evaluations[method][route][pair][variant]
            except KeyError as err:
                raise ValueError(f"evaluations: method {method!r} has no {route}/{pair}/"
                                 f"{variant} metrics (missing key {err})") from err
            missing = [key for key in METRIC_KEYS if key not in values]
            if missing:
                raise ValueError(f"evaluations: {method} {route}/{pair}/{variant} lacks "
                                 f"metrics {missing}")
            nested.setdefault(route, {}).setdefault(pair, {})[method] = {
                key: as_float(values[key]) for key in METRIC_KEYS + OPTIONAL_METRIC_KEYS
                if key in values}
    return nested


def _route_pair_order(evaluations: Mapping[str, Mapping], *, methods: Sequence[str],
                      pair_order: Sequence[tuple[str, str]]) -> list[tuple[str, str]]:
    """Every (route, pair) of any method, listed ones first, then in file order."""
    unknown = [m for m in methods if m not in evaluations]
    if unknown:
        raise ValueError(f"evaluations: no evaluation for methods {unknown}")
    seen = [(route, pair) for method in methods
            for route, pairs in evaluations[method].items() for pair in pairs]
    present = list(dict.fromkeys(seen))
    listed = [rp for rp in dict.fromkeys(map(tuple, pair_order)) if rp in present]
    rest = [rp for rp in present if rp not in listed]
    # group the remaining pairs under their route, keeping routes in first-seen order
    ordered = listed + rest
    routes = list(dict.fromkeys(route for route, _ in ordered))
    return [(route, pair) for route in routes for (r, pair) in ordered if r == route]


def route_pairs(nested: Nested) -> list[tuple[str, str]]:
    """The ``(route, pair)`` keys of a nested metrics dict, in its order."""
    return [(route, pair) for route, pairs in nested.items() for pair in pairs]


def metric_value(nested: Nested, route: str, pair: str, method: str, metric: str) -> float:
    """One value of a nested metrics dict; NaN when absent."""
    return as_float(nested.get(route, {}).get(pair, {}).get(method, {}).get(metric))


def method_summary(nested: Nested, *, methods: Sequence[str],
                   keys: Mapping[str, str] = SUMMARY_KEYS) -> dict:
    """Per method, the mean of each summary metric over every route and pair (NaN skipped).

    Parameters
    ----------
    nested : mapping
        ``{route: {pair: {method: {metric: value}}}}`` (one protocol variant).
    methods : sequence of str
        Methods, in order.
    keys : mapping
        Output key -> metric (default :data:`SUMMARY_KEYS`: R@100P, AUC-PR, AUC-ROC, R@1, R@5,
        single-frame R@1).

    Returns
    -------
    dict
        ``{method: {key: float | None}}``, rounded to 4 decimals (None when no pair has a
        value): ``len(methods) * len(keys)`` values, a compact view for ``dvc metrics show``.
    """
    summary = {}
    for method in methods:
        row: dict = {}
        for key, metric in keys.items():
            finite = [v for v in (metric_value(nested, r, p, method, metric)
                                  for r, p in route_pairs(nested)) if math.isfinite(v)]
            row[key] = round(sum(finite) / len(finite), 4) if finite else None
        summary[method] = row
    return summary


def recall_at_k_table(nested: Nested, *, methods: Sequence[str], labels: Mapping[str, str],
                      ks: Sequence[int] = RECALL_KS) -> pd.DataFrame:
    """recall@K per method, after sequence matching and single-frame, mean over route pairs.

    Returns
    -------
    DataFrame
        Index ``(method, matching)`` with matching ``"sequence (SeqSLAM)"`` or
        ``"single frame"``; columns ``"R@K"`` for each K; float fractions, the mean over every
        route and pair with a value (NaN when none has).
    """
    rows, index = [], []
    for method in methods:
        for prefix, matching in (("", "sequence (SeqSLAM)"), ("single_frame_", "single frame")):
            row = []
            for k in ks:
                values = [metric_value(nested, r, p, method, f"{prefix}recall_at_{k}")
                          for r, p in route_pairs(nested)]
                finite = [v for v in values if math.isfinite(v)]
                row.append(sum(finite) / len(finite) if finite else math.nan)
            rows.append(row)
            index.append((labels[method], matching))
    return pd.DataFrame(rows, index=pd.MultiIndex.from_tuples(index, names=["method", "matching"]),
                        columns=[f"R@{k}" for k in ks], dtype=float)


def _columns(nested: Nested) -> pd.MultiIndex:
    return pd.MultiIndex.from_tuples(route_pairs(nested), names=["route", "pair"])


# ---------------------------------------------------------------------------------------------
# Building tables (raw values)
# ---------------------------------------------------------------------------------------------

def recall_at_100p_table(nested: Nested, *, methods: Sequence[str], labels: Mapping[str, str],
                         with_paper: bool = True) -> pd.DataFrame:
    """Table II: recall at 100% precision per method, route and pair.

    Parameters
    ----------
    nested : mapping
        ``{route: {pair: {method: {metric: value}}}}`` (paper setting).
    methods : sequence of str
        Row order. ``labels[method]`` is the row label.
    with_paper : bool
        Add, under each method the paper also reports, a row with the paper's Table II value
        for the columns whose route and pair match the paper's (rows only when some column
        matches).

    Returns
    -------
    DataFrame
        Index ``(method, source)`` with ``source`` = ``"this run"`` or ``"paper: <label>"``;
        columns ``(route, pair)``; float fractions, NaN where missing.
    """
    columns = _columns(nested)
    matches_paper = with_paper and any(
        not math.isnan(paper.paper_recall_at_100p(route, pair, "sad")) for route, pair in columns)
    rows, index = [], []
    for method in methods:
        rows.append([metric_value(nested, r, p, method, "recall_at_100p") for r, p in columns])
        index.append((labels[method], THIS_RUN))
        if matches_paper and method in paper.PAPER_METHOD_LABELS:
            rows.append([paper.paper_recall_at_100p(r, p, method) for r, p in columns])
            index.append((labels[method], f"paper: {paper.PAPER_METHOD_LABELS[method]}"))
    return pd.DataFrame(rows, index=pd.MultiIndex.from_tuples(index, names=["method", "source"]),
                        columns=columns, dtype=float)


def auc_table(nested: Nested, *, methods: Sequence[str], labels: Mapping[str, str],
              metrics: Sequence[str] = ("auc_roc", "auc_pr")) -> pd.DataFrame:
    """Areas under the ROC and PR curves per method, route and pair (Fig. 10 as a table).

    Returns
    -------
    DataFrame
        Index ``(method, metric)`` (metric display names); columns ``(route, pair)``.
    """
    columns = _columns(nested)
    rows, index = [], []
    for method in methods:
        for metric in metrics:
            rows.append([metric_value(nested, r, p, method, metric) for r, p in columns])
            index.append((labels[method], METRIC_LABELS[metric]))
    return pd.DataFrame(rows, index=pd.MultiIndex.from_tuples(index, names=["method", "metric"]),
                        columns=columns, dtype=float)


def ablation_table(selected: Nested, paper_setting: Nested, *, methods: Sequence[str],
                   labels: Mapping[str, str],
                   metrics: Sequence[str] = ("recall_at_100p", "auc_pr")) -> pd.DataFrame:
    """The same metrics under each method's selected protocol and under the paper's protocol.

    Returns
    -------
    DataFrame
        Index ``(method, metric, setting)``; columns ``(route, pair)`` of ``selected``.
    """
    columns = _columns(selected)
    rows, index = [], []
    for method in methods:
        for metric in metrics:
            for variant, nested in (("selected", selected), ("paper", paper_setting)):
                rows.append([metric_value(nested, r, p, method, metric) for r, p in columns])
                index.append((labels[method], METRIC_LABELS[metric], VARIANT_LABELS[variant]))
    return pd.DataFrame(rows, index=pd.MultiIndex.from_tuples(
        index, names=["method", "metric", "setting"]), columns=columns, dtype=float)


#: Columns of Table III, in order.
INFERENCE_COLUMNS = ("device", "batch-1 ms/frame", "batched ms/frame", "batch size", "repeats",
                     "code", "bytes/frame", "paper ms/frame", "paper bytes/frame")


def inference_table(infos: Mapping[str, Mapping], *, methods: Sequence[str]) -> pd.DataFrame:
    """Table III: inference time per frame and storage per frame of every method.

    Parameters
    ----------
    infos : mapping
        ``{method: info}`` from ``data/features/<method>/info.json`` (``label``, ``dim``,
        ``dtype``, ``bytes_per_frame``, ``timing {device, batch1_ms, batched_ms, batch_size,
        repeats}``).

    Returns
    -------
    DataFrame
        Index = method labels; columns :data:`INFERENCE_COLUMNS`. ``paper ms/frame`` is the
        paper's Table III range (``"3.2–3.4"``; GTA V frames on a Titan X), text.
    """
    rows, index = [], []
    for method in methods:
        info = infos[method]
        timing = info.get("timing") or {}
        low, high = paper.paper_inference_ms_range(method)
        paper_ms = "" if math.isnan(low) else (f"{low:.1f}" if low == high
                                                 else f"{low:.1f}–{high:.1f}")
        code = f"{info.get('dim', '?')} x {info.get('dtype', '?')}"
        rows.append([str(timing.get("device", "unknown")), as_float(timing.get("batch1_ms")),
                     as_float(timing.get("batched_ms")), as_float(timing.get("batch_size")),
                     as_float(timing.get("repeats")), code,
                     as_float(info.get("bytes_per_frame")), paper_ms,
                     as_float(paper.PAPER_BYTES_PER_FRAME.get(method))])
        index.append(info["label"])
    return pd.DataFrame(rows, index=pd.Index(index, name="method"), columns=list(INFERENCE_COLUMNS))


#: Columns of the invariance table: file key -> display name.
INVARIANCE_COLUMNS = {
    "normalisation": "normalisation",
    "same_place": "same place",
    "other_place": "other place",
    "ratio": "ratio",
    "single_frame_recall_at_1": "single-frame r@1",
    "raw_ratio": "ratio (raw codes)",
    "raw_single_frame_recall_at_1": "single-frame r@1 (raw codes)",
    "classifier_accuracy": "weather classifier accuracy",
}


def invariance_table(invariance: Mapping[str, Mapping[str, Mapping]], *,
                     methods: Sequence[str], labels: Mapping[str, str]) -> pd.DataFrame:
    """Weather invariance of the codes, per route and method.

    Parameters
    ----------
    invariance : mapping
        ``{route: {method: {normalisation, same_place, other_place, ratio,
        single_frame_recall_at_1, raw_*, classifier_accuracy?}}}``
        (``data/evaluation/invariance.json``).

    Returns
    -------
    DataFrame
        Index ``(route, method)``; columns the display names of :data:`INVARIANCE_COLUMNS`
        (``normalisation`` text, the rest float, NaN where absent). Methods absent from the
        file are left out.
    """
    rows, index = [], []
    for route, per_method in invariance.items():
        for method in methods:
            if method not in per_method:
                continue
            stats = per_method[method]
            rows.append([str(stats.get(key, MISSING)) if key == "normalisation"
                         else as_float(stats.get(key)) for key in INVARIANCE_COLUMNS])
            index.append((route, labels.get(method, method)))
    return pd.DataFrame(rows, index=pd.MultiIndex.from_tuples(index, names=["route", "method"])
                        if index else pd.MultiIndex.from_tuples([], names=["route", "method"]),
                        columns=list(INVARIANCE_COLUMNS.values()))


#: Columns of the protocol table.
PROTOCOL_COLUMNS = ("selected protocol", "validation R@100P", "validation AUC-PR",
                    "paper protocol: validation R@100P", "paper protocol: validation AUC-PR",
                    "candidates")


def protocol_table(records: Mapping[str, Mapping], *, methods: Sequence[str],
                   labels: Mapping[str, str]) -> pd.DataFrame:
    """Each method's matching protocol and its validation scores (``data/protocol/*.json``).

    Returns
    -------
    DataFrame
        Index ``method`` (label); columns :data:`PROTOCOL_COLUMNS`; a record without
        candidates (no validation drives) shows its ``fallback`` reason as the protocol.
    """
    rows, index = [], []
    for method in methods:
        record = records[method]
        by_label = {c["label"]: c for c in record.get("candidates", [])}
        chosen = by_label.get(record["selected"]["label"], {})
        paper = by_label.get((record.get("paper") or {}).get("label"), {})
        text = record["selected"]["label"]
        if record.get("fallback"):
            text += f" (fallback: {record['fallback']})"
        rows.append([text, as_float(chosen.get("mean_recall_at_100p")),
                     as_float(chosen.get("mean_auc_pr")),
                     as_float(paper.get("mean_recall_at_100p")),
                     as_float(paper.get("mean_auc_pr")), len(by_label)])
        index.append(labels.get(method, method))
    return pd.DataFrame(rows, index=pd.Index(index, name="method"),
                        columns=list(PROTOCOL_COLUMNS))


def layer_choice_table(selection: Mapping[str, Any]) -> pd.DataFrame:
    """The ``dnn`` (input side, layer) candidates and their validation scores (``info.json``
    ``layer_selection`` of the ``dnn`` features).

    Returns
    -------
    DataFrame
        Index ``candidate`` (``"block7, 128 px"``; the layer alone for rows written before the
        input side was chosen); columns ``validation R@100P``, ``validation AUC-PR``,
        ``validation single-frame R@1`` and ``chosen`` (``yes`` or empty).
    """
    rows, index = [], []
    chosen = (selection.get("selected"), selection.get("image_size"))
    for row in selection.get("candidates", []):
        rows.append([as_float(row.get("val/recall_at_100p")), as_float(row.get("val/auc_pr")),
                     as_float(row.get("val/single_frame_recall_at_1")),
                     "yes" if (row["layer"], row.get("image_size")) == chosen else ""])
        size = row.get("image_size")
        index.append(row["layer"] if size is None else f"{row['layer']}, {size} px")
    return pd.DataFrame(rows, index=pd.Index(index, name="candidate"),
                        columns=["validation R@100P", "validation AUC-PR",
                                 "validation single-frame R@1", "chosen"])


#: A validation curve has flattened once it is within this much (absolute) of its best value.
PLATEAU_TOLERANCE = 0.02


def plateau_iteration(iterations: Sequence[float], values: Sequence[float], *,
                      tolerance: float = PLATEAU_TOLERANCE) -> float:
    """The first logged iteration whose value is within ``tolerance`` of the curve's best.

    Parameters
    ----------
    iterations, values : sequences of the same length
        A validation curve (NaN values are ignored).

    Returns
    -------
    float
        NaN when the curve has no finite value.
    """
    it = np.asarray(iterations, dtype=float)
    val = np.asarray(values, dtype=float)
    keep = np.isfinite(val)
    if not keep.any():
        return float("nan")
    it, val = it[keep], val[keep]
    return float(it[np.argmax(val >= val.max() - tolerance)])


def validation_curve_table(logs: Mapping[str, pd.DataFrame], *,
                           selections: Mapping[str, Mapping] | None = None,
                           metric: str = "val/recall_at_100p") -> pd.DataFrame:
    """Per model: the validation metric logged during training, where it starts, peaks, ends
    and flattens (:func:`plateau_iteration`), and the iteration whose weights ``model.pt``
    keeps (NaN without a ``selection.json``).

    Parameters
    ----------
    logs : mapping
        ``{model name: train_log.csv as a DataFrame}``; models without ``metric`` are skipped.
    selections : mapping, optional
        ``{model name: selection.json}`` (:func:`cmal_lcd.models.training.selection_record`).
    """
    selections = selections or {}
    rows, index = [], []
    for name, log in logs.items():
        if metric not in log:
            continue
        curve = log[["iteration", metric]].dropna()
        if curve.empty:
            continue
        best = int(curve[metric].to_numpy().argmax())
        rows.append([float(curve[metric].iloc[0]), float(curve[metric].iloc[best]),
                     float(curve["iteration"].iloc[best]), float(curve[metric].iloc[-1]),
                     float(curve["iteration"].iloc[-1]),
                     plateau_iteration(curve["iteration"], curve[metric]),
                     float(selections.get(name, {}).get("iteration", math.nan))])
        index.append(name)
    return pd.DataFrame(rows, index=pd.Index(index, name="model"),
                        columns=["start", "best", "best at iteration", "last",
                                 "last iteration", "within 2 points of best from",
                                 "model.pt keeps iteration"])
