"""The report's sections: each writes its tables or figures and returns README entries.

A section function takes plain data (nested metrics dicts, per-method JSON dicts, DataFrames,
arrays), writes its files under ``out_dir`` (``tables/`` or ``figures/``) and returns its
:class:`cmal_lcd.reports.readme.Entry` objects (title, description, files, inlined Markdown, or
why it was not produced); its captions and descriptions live with it.

- :mod:`.results`: matching protocol, Table II, AUC, recall@K, Table III, ablation;
- :mod:`.invariance`: condition invariance of the codes (``invariance.json``);
- :mod:`.loops`: loop closure within one drive (``data/evaluation_loops``);
- :mod:`.choices`: the DNN layer and where training flattens (choices made on validation);
- :mod:`.world`: Fig. 1 and the world map;
- :mod:`.matrices`: Fig. 6;
- :mod:`.curves`: Figs. 8-9 and Fig. 10;
- :mod:`.reconstructions`: Fig. 11;
- :mod:`.training`: training curves.

:func:`table_entries` and :func:`figure_entries` run them in README order.
"""

from __future__ import annotations

from pathlib import Path
from typing import Mapping

from cmal_lcd.paths import REPO
from cmal_lcd.reports import figures
from cmal_lcd.reports.inputs import OptionalFiles, RunFiles
from cmal_lcd.reports.readme import Entry
from cmal_lcd.reports.sections import (choices, curves, invariance, loops, matrices,
                                       reconstructions, results, training, world)


def table_entries(out_dir: Path, run: RunFiles, optional: OptionalFiles, *,
                  selected: Mapping, paper_setting: Mapping,
                  loop_metrics: Mapping[str, Mapping | None] | None = None,
                  loops_dir: Path | None = None,
                  d_thresh: int) -> list[Entry]:
    """Every table: the result tables, condition invariance, loop closure within one drive,
    then the validation choices.

    ``selected``, ``paper_setting``: ``{route: {pair: {method: {metric: value}}}}``;
    ``loop_metrics``: ``{method: evaluate_loops's metrics.json or None}``
    (:func:`cmal_lcd.reports.inputs.read_loop_metrics` of ``loops_dir``; None: every method's
    is missing); ``d_thresh``: ``matching.d_thresh``, the main tables' tolerance.
    """
    methods, labels = run.methods, run.labels
    loop_metrics = loop_metrics if loop_metrics is not None else {}
    return [*results.result_entries(out_dir, selected=selected, paper_setting=paper_setting,
                                    protocols=run.protocols, infos=run.infos, methods=methods,
                                    labels=labels, d_thresh=d_thresh,
                                    strict=run.strict_metrics()),
            invariance.invariance_entry(out_dir, optional.invariance,
                                        source=optional.invariance_path, methods=methods,
                                        labels=labels),
            loops.loops_entry(out_dir, loop_metrics, methods=methods, labels=labels,
                              source=loops_dir if loops_dir is not None else REPO.loops),
            *choices.choice_entries(out_dir, infos=run.infos, logs=optional.train_logs,
                                    selections=optional.selections)]


def figure_entries(out_dir: Path, run: RunFiles, optional: OptionalFiles, *,
                   selected: Mapping, pr_curves: Mapping,
                   d_thresh: int | None = None) -> list[Entry]:
    """Every figure: Fig. 1 and the map, Fig. 6, Figs. 8-9, Fig. 10, Fig. 11, training curves.

    ``pr_curves``: ``{route: {pair: {method: DataFrame (recall, precision, threshold)}}}``;
    ``d_thresh``: ``matching.d_thresh`` (Fig. 6's true-place band).
    """
    methods, labels = run.methods, run.labels
    styles = figures.method_styles(methods)
    return [*world.world_entries(out_dir, optional.dataset, missing=optional.dataset_missing),
            *matrices.matrix_entries(out_dir, optional.matrices, labels=labels,
                                     d_thresh=d_thresh),
            *curves.pr_entries(out_dir, pr_curves, labels=labels, styles=styles),
            curves.auc_bars_entry(out_dir, selected, methods=methods, labels=labels,
                                  styles=styles),
            reconstructions.reconstruction_entry(out_dir, optional.reconstructions,
                                                 missing=optional.reconstructions_missing,
                                                 conditions=run.conditions),
            *training.training_entries(out_dir, optional.train_logs,
                                       sources=optional.train_log_paths,
                                       selections=optional.selections)]
