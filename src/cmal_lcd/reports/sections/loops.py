"""The table "loop closure within one drive" from ``data/evaluation_loops/<method>/metrics.json``
(stage ``evaluate_loops``): every method on every looping route, weather change or not."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Mapping, Sequence

import pandas as pd

from cmal_lcd.reports import render
from cmal_lcd.reports.readme import Entry
from cmal_lcd.reports.sections.entries import not_produced, table_entry

TITLE = "Loop closure within one drive"
#: The two metrics shown per method: key -> column suffix.
LOOP_METRICS = {"recall_at_100p": "R@100P", "auc_pr": "AUC-PR"}


def loop_kind(name: str) -> str:
    """``sunny-rainy`` -> ``sunny then rainy (weather change)``; ``sunny-sunny`` -> same weather."""
    first, _, second = name.partition("-")
    kind = "same weather" if first == second else "weather change"
    return f"{first} then {second} ({kind})"


def loop_table(loops: Mapping[str, Mapping], *, methods: Sequence[str],
               labels: Mapping[str, str]) -> pd.DataFrame:
    """Rows (index ``route, loop``): every route's loops, then the mean over routes of every
    loop; columns: R@100P and AUC-PR of each method (NaN where a method lacks the loop).

    Parameters
    ----------
    loops : mapping
        ``{method: {route: {loop: {metric: value}}}}``.
    """
    keys = list(dict.fromkeys((route, loop) for method in methods
                              for route, by_loop in loops[method].items() for loop in by_loop))
    rows = []
    for route, loop in keys:
        row = {"route": route, "loop": loop_kind(loop)}
        for method in methods:
            values = loops[method].get(route, {}).get(loop, {})
            for key, suffix in LOOP_METRICS.items():
                row[f"{labels.get(method, method)} {suffix}"] = values.get(key, math.nan)
        rows.append(row)
    table = pd.DataFrame(rows)
    value_columns = [c for c in table.columns if c not in ("route", "loop")]
    means = (table.groupby("loop", sort=False)[value_columns].mean().reset_index()
             .assign(route="mean"))
    return pd.concat([table, means[table.columns]], ignore_index=True).set_index(["route",
                                                                                  "loop"])


def loops_entry(out_dir: Path, loops: Mapping[str, Mapping | None], *, source: Path,
                methods: Sequence[str], labels: Mapping[str, str]) -> Entry:
    """``tables/loops``, or why not (a method's results are missing, or the dataset has no
    looping route).

    Parameters
    ----------
    loops : mapping
        ``{method: metrics.json content or None (file absent)}``; a content of
        ``{"skipped": reason}`` means the dataset has no looping route.
    source : Path
        ``data/evaluation_loops`` (named when files are missing).
    """
    absent = [m for m in methods if loops.get(m) is None]
    if absent:
        return not_produced(TITLE, f"no `{source}/<method>/metrics.json` for {absent} (the "
                                   "evaluate_loops stage did not run).")
    skipped = [loops[m]["skipped"] for m in methods if "skipped" in loops[m]]
    if skipped:
        return not_produced(TITLE, f"{skipped[0]}.")
    table = loop_table(loops, methods=methods, labels=labels)
    return table_entry(
        render.render_table(table, caption="Loop closure within one drive: a looping route "
                            "driven twice in one run (lap 1 then lap 2), R@100P and AUC-PR of "
                            "every method under its selected protocol.", label="tab:loops"),
        out_dir / "tables" / "loops", out_dir, title=TITLE,
        description="Each test route driven twice in the same direction within one "
                    "sequence (the return leg between the laps is not rendered), the weather "
                    "changing between the laps or, as a control, not. Every frame is matched "
                    "against its older frames outside the exclusion zone (SeqSLAM on the "
                    "self-difference matrix); a lap-2 frame within the pose tolerance of a "
                    "lap-1 frame has a revisit, lap-1 frames have none. Each method uses the "
                    "protocol chosen on the validation drives (lap 1 is the reference drive "
                    "of its normalisation). Mean: over the test routes (docs/loops.md).")
