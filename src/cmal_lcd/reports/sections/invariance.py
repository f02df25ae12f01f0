"""The condition-invariance table from ``data/evaluation/invariance.json`` (analyse_codes)."""

from __future__ import annotations

from pathlib import Path
from typing import Mapping, Sequence

from cmal_lcd.reports import render, tables
from cmal_lcd.reports.readme import Entry
from cmal_lcd.reports.sections.entries import not_produced, table_entry

TITLE = "Condition invariance of the codes"


def invariance_entry(out_dir: Path, invariance: Mapping | None, *, source: Path,
                     methods: Sequence[str], labels: Mapping[str, str]) -> Entry:
    """``tables/invariance``, or why not when ``invariance`` is None.

    Parameters
    ----------
    invariance : mapping or None
        ``{route: {method: {same_place, other_place, ratio, single_frame_recall_at_1, raw_*,
        normalisation}}}`` (None: the analysis did not run).
    source : Path
        Where ``invariance.json`` was looked for (named when it is missing).
    """
    if invariance is None:
        return not_produced(TITLE, f"`{source}` does not exist (the code-invariance analysis "
                                   "did not run).")
    inv = tables.invariance_table(invariance, methods=methods, labels=labels)
    return table_entry(
        render.render_table(inv, caption="Weather invariance of the codes, across weathers: "
                            "mean difference to the same place and to other places "
                            "(after each method's selected normalisation; mean over the "
                            "route's test pairs).",
                            label="tab:invariance", default=render.format_number,
                            columns={"weather classifier accuracy": render.format_percent,
                                     "single-frame r@1": render.format_percent,
                                     "single-frame r@1 (raw codes)": render.format_percent}),
        out_dir / "tables" / "invariance", out_dir, title=TITLE,
        description="For every cross-weather test pair, with codes normalised as the "
                    "method's selected protocol does: the mean difference (the method's "
                    "own: eq. 13 for codes, SAD for thumbnails) between a query and the "
                    "reference frame of its true place, and between it and reference frames "
                    "more than D_thresh frames away (other places, also under the other "
                    "weather). Their ratio is scale-free: lower = the place dominates the "
                    "code. Single-frame r@1: nearest reference frame within D_thresh of the "
                    "true place, no sequence. The raw-code columns repeat the ratio and "
                    "r@1 without normalisation. The accuracy is CMAL's weather classifier C "
                    "on the test frames.")
