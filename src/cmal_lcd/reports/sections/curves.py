"""Figs. 8-9 (precision-recall curves, one figure per route) and Fig. 10 (AUC bars)."""

from __future__ import annotations

from pathlib import Path
from typing import Mapping, Sequence

from cmal_lcd.reports import figures
from cmal_lcd.reports.readme import Entry
from cmal_lcd.reports.sections.entries import figure_files


def pr_entries(out_dir: Path, curves: Mapping, *, labels: Mapping[str, str],
               styles: Mapping) -> list[Entry]:
    """Figs. 8-9: ``figures/fig08-09_pr_<route>.{png,pdf}`` per route.

    Parameters
    ----------
    curves : mapping
        ``{route: {pair: {method: DataFrame (recall, precision, threshold)}}}``.
    styles : mapping
        :func:`cmal_lcd.reports.figures.method_styles`.
    """
    entries = []
    for route, per_pair in curves.items():
        fig = figures.pr_curves_figure(per_pair, route=route, labels=labels, styles=styles)
        paths = figures.save_figure(fig, out_dir / "figures" / f"fig08-09_pr_{route}")
        entries.append(Entry(
            title=f"Figs. 8-9: precision-recall curves, {route}",
            description="Precision against recall of every method on each reference-query "
                        "pair of this route, sweeping the SeqSLAM confidence threshold; a curve "
                        "that stays at precision 1 further to the right has higher "
                        "recall@100%P.", files=figure_files(paths, out_dir)))
    return entries


def auc_bars_entry(out_dir: Path, selected: Mapping, *, methods: Sequence[str],
                   labels: Mapping[str, str], styles: Mapping) -> Entry:
    """Fig. 10: ``figures/fig10_auc.{png,pdf}``, AUC-ROC and AUC-PR bars of ``selected``
    (``{route: {pair: {method: {metric: value}}}}``)."""
    paths = figures.save_figure(
        figures.auc_bars_figure(selected, methods=methods, labels=labels, styles=styles),
        out_dir / "figures" / "fig10_auc")
    return Entry(
        title="Fig. 10: area under the curve", files=figure_files(paths, out_dir),
        description="AUC-ROC (top) and AUC-PR (bottom) of every method on every route and "
                    "pair; higher bars mean a more reliable loop closure score.")
