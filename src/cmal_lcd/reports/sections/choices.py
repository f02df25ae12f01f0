"""Tables of the choices made on validation drives besides the protocol: the ``dnn`` layer and
the ``dnn_head`` input side (``info.json``'s ``layer_selection``), and where each model's
validation curve flattens (``train_log.csv``, the ``iterations`` choice)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Mapping

import pandas as pd

from cmal_lcd.reports import render, tables
from cmal_lcd.reports.readme import Entry
from cmal_lcd.reports.sections.entries import table_entry


#: Per method with a ``layer_selection``: ``(table file, LaTeX label, what was chosen, title,
#: the candidates)``.
LAYER_CHOICES = {
    "dnn": ("dnn_layer", "tab:dnn-layer", "DNN layer and input side",
            "DNN layer and input size chosen on validation",
            "Every EfficientNet-Lite0 block of `features.dnn.layer_candidates` at every input side "
            "of `features.dnn.image_size_candidates` (a block whose map is smaller than the grid "
            "at a side is left out), pooled to the configured grid"),
    "dnn_head": ("dnn_head_side", "tab:dnn-head-side", "DNN pooled head (ablation) input side",
                 "DNN pooled head: input size chosen on validation",
                 "The global-pooled EfficientNet-Lite0 head at every input side of "
                 "`features.dnn.image_size_candidates`"),
}


def layer_choice_entry(out_dir: Path, method: str, selection: Mapping) -> Entry:
    """``tables/<file>`` of :data:`LAYER_CHOICES`: every candidate (layer, input side) of
    ``method`` with its validation scores.

    ``selection`` is ``data/features/<method>/info.json``'s ``layer_selection``
    (``protocol``, ``criterion``, the candidates and the chosen one).
    """
    file, label, what, title, candidates = LAYER_CHOICES[method]
    return table_entry(
        render.render_table(tables.layer_choice_table(selection),
                            caption=f"{what}, chosen by the extract_features stage on the "
                                    "validation drives (mean over validation pairs; codes "
                                    f"{selection.get('protocol', '')}).",
                            label=label),
        out_dir / "tables" / file, out_dir, title=title,
        description=f"{candidates}, scored on the validation drives; the best mean "
                    f"{selection.get('criterion')} won. Source: "
                    f"`data/features/{method}/info.json` (`layer_selection`).")


def whole_or_missing(value: float) -> str:
    """``200.0 -> "200"``; NaN (no ``selection.json``) -> the tables' missing mark."""
    return render.MISSING if math.isnan(value) else f"{value:.0f}"


def validation_curve_entry(out_dir: Path, curve: pd.DataFrame) -> Entry:
    """``tables/validation_curve`` from :func:`cmal_lcd.reports.tables.validation_curve_table`
    (one row per model)."""
    return table_entry(
        render.render_table(curve, caption="Validation recall@100%P logged during "
                            "training (mean over validation pairs; codes centred by the "
                            "training mean of their nearest condition, L2, no enhancement).",
                            label="tab:validation-curve",
                            columns={"best at iteration": lambda v: f"{v:.0f}",
                                     "last iteration": lambda v: f"{v:.0f}",
                                     "within 2 points of best from": lambda v: f"{v:.0f}",
                                     "model.pt keeps iteration": whole_or_missing}),
        out_dir / "tables" / "validation_curve", out_dir,
        title="Where training flattens (iterations)",
        description="`start` is the untrained model (iteration 0). `models.<name>."
                    "iterations` is chosen from this curve (see the training-curve "
                    "figures, `val` panel); `within 2 points of best from` is the first "
                    "logged iteration within 2 points of the best value. With `models.<name>."
                    "select: best_validation` the weights every later stage uses are those "
                    "of the best validated iteration (never iteration 0; `model.pt keeps "
                    "iteration`), chosen on these validation drives only. Sources: "
                    "`models/<name>/train_log.csv`, `models/<name>/selection.json`.")


def choice_entries(out_dir: Path, *, infos: Mapping[str, dict],
                   logs: Mapping[str, pd.DataFrame],
                   selections: Mapping[str, dict] | None = None) -> list[Entry]:
    """The DNN-layer table (when the ``dnn`` method chose a layer), the pooled head's side
    table (when ``dnn_head`` chose one) and the validation-curve table (when a training log
    has validation columns); no entry for any of them otherwise.

    Parameters
    ----------
    infos : mapping
        ``{method: info.json}``.
    logs : mapping
        ``{model name: train_log.csv}`` of the models that have a log.
    selections : mapping, optional
        ``{model name: selection.json}``: the iteration each ``model.pt`` keeps.
    """
    entries = []
    for method in LAYER_CHOICES:
        selection = (infos.get(method) or {}).get("layer_selection")
        if selection:
            entries.append(layer_choice_entry(out_dir, method, selection))
    curve = tables.validation_curve_table(logs, selections=selections)
    if not curve.empty:
        entries.append(validation_curve_entry(out_dir, curve))
    return entries
