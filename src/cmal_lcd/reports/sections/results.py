"""The result tables: matching protocol, Table II, AUC, recall@K, Table III and the ablation.

Each ``*_entry`` function builds one table from plain data (nested metrics
``{route: {pair: {method: {metric: value}}}}``, per-method JSON dicts), writes it as
``tables/<name>.{md,csv,tex}`` under ``out_dir`` and returns its README entry, caption and
description included.
"""

from __future__ import annotations

from pathlib import Path
from typing import Mapping, Sequence

from cmal_lcd.reports import render, tables
from cmal_lcd.reports.readme import Entry, all_protocols_fell_back
from cmal_lcd.reports.sections.entries import table_entry


def _table_section(out_dir: Path, table, name: str, *, caption: str, label: str, title: str,
                   description: str, **formats) -> Entry:
    """Render ``table`` (``formats``: ``default``/``columns`` of
    :func:`cmal_lcd.reports.render.render_table`), write it as ``tables/<name>.{md,csv,tex}``
    under ``out_dir`` and return its README entry."""
    return table_entry(render.render_table(table, caption=caption, label=label, **formats),
                       out_dir / "tables" / name, out_dir, title=title,
                       description=description)


def protocol_entry(out_dir: Path, protocols: Mapping[str, dict], *, methods: Sequence[str],
                   labels: Mapping[str, str]) -> Entry:
    """``tables/protocol``: each method's matching protocol and its validation scores.

    ``protocols`` is ``{method: protocol/<method>.json}``.
    """
    protocol = tables.protocol_table(protocols, methods=methods, labels=labels)
    return _table_section(
        out_dir, protocol, "protocol",
        caption="Matching protocol per method, chosen by the select_protocol stage on the "
                "validation drives (mean over the validation pairs); never tuned on a test "
                "route.",
        label="tab:protocol", columns={"candidates": lambda v: f"{v:.0f}"},
        title="Matching protocol per method",
        description="What each method's codes go through before SeqSLAM: centring (none; the "
                    "reference map's mean code; or the training-set mean code of the frame's "
                    "nearest weather), L2 normalisation, and contrast enhancement (eq. 14) with "
                    "its window. Every combination was scored on the validation drives; the "
                    "best mean recall@100%P won (ties: AUC-PR). The paper protocol's "
                    "validation scores are beside it. Source: `data/protocol/<method>.json`, "
                    "which also holds every candidate's per-pair scores.")


def recall_at_100p_entry(out_dir: Path, selected: Mapping, *, methods: Sequence[str],
                         labels: Mapping[str, str]) -> Entry:
    """``tables/table2_recall_at_100p``: paper Table II, our numbers beside the paper's."""
    table2 = tables.recall_at_100p_table(selected, methods=methods, labels=labels)
    return _table_section(
        out_dir, table2, "table2_recall_at_100p",
        caption="Table II: recall at 100% precision, per route and reference-query pair (each "
                "method's protocol chosen on the validation drives); 'paper' rows are the "
                "paper's GTA V numbers.",
        label="tab:recall-at-100p", title="Table II: recall at 100% precision",
        description="The share of true loop closures found before the first false one, per "
                    "method and pair, with the paper's Table II values under each method where "
                    "route and pair match the paper's.")


def auc_entry(out_dir: Path, selected: Mapping, *, methods: Sequence[str],
              labels: Mapping[str, str]) -> Entry:
    """``tables/auc``: AUC-ROC and AUC-PR per method and pair (paper Fig. 10 as numbers)."""
    auc = tables.auc_table(selected, methods=methods, labels=labels)
    return _table_section(
        out_dir, auc, "auc",
        caption="Area under the ROC and precision-recall curves (selected protocols).",
        label="tab:auc", title="AUC-ROC and AUC-PR",
        description="Threshold-free summaries of each PR/ROC curve (paper Fig. 10 as numbers); "
                    "the paper gives these only as a bar chart, so there is no paper column.")


def recall_at_k_entry(out_dir: Path, selected: Mapping, *, methods: Sequence[str],
                      labels: Mapping[str, str]) -> Entry:
    """``tables/recall_at_k``: recall@K after sequence matching and single-frame."""
    recall_k = tables.recall_at_k_table(selected, methods=methods, labels=labels)
    return _table_section(
        out_dir, recall_k, "recall_at_k",
        caption="recall@K: the share of scored queries with a reference frame within D_thresh "
                "of the true place among their K best, after sequence matching and "
                "single-frame (mean over routes and pairs; selected protocols).",
        label="tab:recall-at-k", title="recall@K",
        description="The place-recognition community's retrieval measure beside the PR "
                    "metrics: a query counts at K when one of the K reference frames ranked "
                    "best (by SeqSLAM's sequence score, or by the frame difference alone) is "
                    "within D_thresh frames of its true place. recall@1 is the match itself; "
                    "recall@K rises with K. Per pair in `metrics.json`; – where the evaluation "
                    "predates recall@K.")


#: Metrics of the strict-tolerance table.
STRICT_METRICS = ("recall_at_100p", "auc_pr", "recall_at_1", "single_frame_recall_at_1")


def strict_entry(out_dir: Path, strict: Mapping, *, d_thresh: int, d_thresh_strict: int,
                 methods: Sequence[str], labels: Mapping[str, str]) -> Entry:
    """``tables/strict_tolerance``: the selected matches scored at ``matching.d_thresh_strict``."""
    table = tables.auc_table(strict, methods=methods, labels=labels, metrics=STRICT_METRICS)
    return _table_section(
        out_dir, table, "strict_tolerance",
        caption=f"The same matches (selected protocols) scored at a strict tolerance: correct "
                f"within {d_thresh_strict} frame(s) of the true place instead of "
                f"{d_thresh} (matching.d_thresh_strict).",
        label="tab:strict-tolerance", title=f"At a strict tolerance (±{d_thresh_strict} frames)",
        description=f"Table I's tolerance (±{d_thresh} frames) can accept a match many places "
                    f"away, so methods that find the right stretch of track but not the frame "
                    f"look alike. Here a match counts only within ±{d_thresh_strict} frame(s) "
                    f"of its true place, fixed in the config before the run "
                    f"(`matching.d_thresh_strict`); the matching itself (protocol, SeqSLAM, "
                    f"trained weights) is the main tables' own. Single-frame recall@1 is the "
                    f"nearest reference frame of each query, without sequence matching.")


def inference_entry(out_dir: Path, infos: Mapping[str, dict], *,
                    methods: Sequence[str]) -> Entry:
    """``tables/table3_inference``: paper Table III, from each method's ``info.json``."""
    table3 = tables.inference_table(infos, methods=methods)
    return _table_section(
        out_dir, table3, "table3_inference",
        caption="Table III: feature inference time per frame (ms, median of repeats, warm-up "
                "excluded) and storage per frame; paper columns from its Table III and "
                "Section IV-D.",
        label="tab:inference", default=render.format_number,
        columns={"batch-1 ms/frame": render.format_ms, "batched ms/frame": render.format_ms},
        title="Table III: inference time and storage",
        description="Milliseconds per frame from a raw frame to its code at batch size 1 and "
                    "batched, on the device named, and the bytes one code takes.")


def ablation_entry(out_dir: Path, selected: Mapping, paper_setting: Mapping, *,
                   methods: Sequence[str], labels: Mapping[str, str]) -> Entry:
    """``tables/ablation_paper_protocol``: selected protocol against the paper's."""
    ablation = tables.ablation_table(selected, paper_setting, methods=methods, labels=labels)
    return _table_section(
        out_dir, ablation, "ablation_paper_protocol",
        caption="Ablation: each method under its protocol chosen on validation drives and "
                "under the paper's protocol (raw codes, eq. 14 with Table I's window).",
        label="tab:ablation-paper-protocol", title="Ablation: the paper's protocol",
        description="The same matching on raw codes with the paper's contrast enhancement "
                    "(eq. 14, Table I), which can flatten the differences of smooth learned "
                    "codes and leaves per-weather code offsets in place; it keeps the paper "
                    "comparison visible.")


def result_entries(out_dir: Path, *, selected: Mapping, paper_setting: Mapping,
                   protocols: Mapping[str, dict], infos: Mapping[str, dict],
                   methods: Sequence[str], labels: Mapping[str, str], d_thresh: int,
                   strict: tuple[Mapping, int] | None = None) -> list[Entry]:
    """The result tables, in README order: six, less the ablation when every protocol fell
    back to the paper's (it would repeat Table II), plus the strict tolerance when ``strict``
    (``(nested metrics, tolerance)``, :meth:`~cmal_lcd.reports.inputs.RunFiles.strict_metrics`)
    is given."""
    return [protocol_entry(out_dir, protocols, methods=methods, labels=labels),
            recall_at_100p_entry(out_dir, selected, methods=methods, labels=labels),
            auc_entry(out_dir, selected, methods=methods, labels=labels),
            recall_at_k_entry(out_dir, selected, methods=methods, labels=labels),
            *([] if strict is None else
              [strict_entry(out_dir, strict[0], d_thresh=d_thresh, d_thresh_strict=strict[1],
                            methods=methods, labels=labels)]),
            inference_entry(out_dir, infos, methods=methods),
            *([] if all_protocols_fell_back(protocols) else
              [ablation_entry(out_dir, selected, paper_setting, methods=methods,
                              labels=labels)])]
