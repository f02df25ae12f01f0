"""The report's machine-readable files: nested metrics, the DVC metrics and the DVC plots.

- ``metrics.json`` / ``metrics_paper.json``: ``{route: {pair: {method: {metric: value}}}}``
  under the selected and the paper's protocol (:func:`write_metrics`);
- ``summary.json``: the DVC metrics, the headline: each method's mean R@100P over routes and
  pairs, ``{"R100P": {method: value}}`` (:func:`headline`). One file with one value per
  method, so that ``dvc metrics show`` prints one short row and ``dvc exp show`` names its
  columns ``R100P.<method>`` with no file prefix: both fit a 120-column terminal with the six
  default methods (``R@100P``, one character more per column, does not);
- ``summary/<method>.json``: six means per method (:func:`write_summary`), not declared as DVC
  metrics (their paths would prefix every ``dvc exp show`` column) but read by DVC all the same:
  ``dvc metrics show -R reports/summary`` (one row per method), ``dvc metrics diff -R --targets
  reports/summary``;
- ``plots/{pr,roc}/<route>/<pair>.csv``: the DVC plots, every method overlaid
  (:func:`write_plots_files`);
- ``plots/training/<model>/<key>.tsv``: each trained model's logged series, copied from its
  dvclive folder, so that ``dvc plots show`` draws the training charts on a fresh clone (the
  models themselves live in the DVC cache) (:func:`write_training_plots`).
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Mapping, Sequence

from cmal_lcd.io import atomic_write_json
from cmal_lcd.reports import plots, tables


#: The summary key of the headline (:func:`headline`): the paper's Table II measure.
HEADLINE_KEY = "R@100P"
#: Its name in ``summary.json``.
HEADLINE_NAME = "R100P"


def headline(summary: Mapping[str, Mapping], *, key: str = HEADLINE_KEY,
             name: str = HEADLINE_NAME) -> dict:
    """``{name: {method: value}}``: the summary key ``key`` of every method (``summary.json``).

    Parameters
    ----------
    summary : mapping
        ``{method: {key: value}}`` from :func:`cmal_lcd.reports.tables.method_summary`.
    """
    return {name: {method: row.get(key) for method, row in summary.items()}}


def write_summary(summary_dir: Path, summary: Mapping[str, Mapping]) -> list[Path]:
    """``<summary_dir>/<method>.json`` per method; other ``*.json`` removed.

    Parameters
    ----------
    summary : mapping
        ``{method: {key: value}}`` from :func:`cmal_lcd.reports.tables.method_summary`.
    """
    summary_dir.mkdir(parents=True, exist_ok=True)
    for stale in summary_dir.glob("*.json"):
        if stale.stem not in summary:
            stale.unlink()
    return [atomic_write_json(summary_dir / f"{method}.json", row)
            for method, row in summary.items()]


def write_metrics(out_dir: Path, *, selected: Mapping, paper_setting: Mapping,
                  methods: Sequence[str]) -> list[Path]:
    """``metrics.json``, ``metrics_paper.json``, ``summary.json`` and ``summary/<method>.json``
    in ``out_dir``.

    Parameters
    ----------
    selected, paper_setting : mapping
        ``{route: {pair: {method: {metric: value}}}}`` under each method's selected protocol
        and under the paper's (:func:`cmal_lcd.reports.tables.metrics_by_route_pair_method`).
    """
    summary = tables.method_summary(selected, methods=methods)
    return [atomic_write_json(out_dir / "metrics.json", selected),
            atomic_write_json(out_dir / "metrics_paper.json", paper_setting),
            atomic_write_json(out_dir / "summary.json", headline(summary)),
            *write_summary(out_dir / "summary", summary)]


def roc_counts(curves: Mapping, evaluations: Mapping) -> dict:
    """``{route: {pair: {method: {"n_positive", "n_scored"}}}}`` for every curve whose
    evaluation (selected protocol) has both counts; the ROC needs them.

    Parameters
    ----------
    curves : mapping
        ``{route: {pair: {method: PR curve}}}``.
    evaluations : mapping
        ``{method: metrics.json}``.
    """
    counts: dict = {}
    for route, per_pair in curves.items():
        for pair, per_method in per_pair.items():
            for method in per_method:
                values = evaluations[method][route][pair]["selected"]
                if "n_positive" in values and "n_scored" in values:
                    counts.setdefault(route, {}).setdefault(pair, {})[method] = {
                        "n_positive": values["n_positive"], "n_scored": values["n_scored"]}
    return counts


#: Where the training series go under ``plots/`` (dvc.yaml's training charts read them).
TRAINING_PLOTS = "training"


def write_training_plots(plots_dir: Path, train_log_paths: Mapping[str, Path]) -> list[Path]:
    """Copy each model's dvclive series (``<model dir>/dvclive/plots/metrics/**/*.tsv``, beside
    its ``train_log.csv`` in ``train_log_paths``) to ``plots/training/<model>/``; earlier
    copies are removed first. Returns the files written."""
    target = plots_dir / TRAINING_PLOTS
    if target.is_dir():
        shutil.rmtree(target)
    written = []
    for name, log_path in train_log_paths.items():
        series = Path(log_path).parent / "dvclive" / "plots" / "metrics"
        for source in sorted(series.rglob("*.tsv")):
            path = target / name / source.relative_to(series)
            path.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(source, path)
            written.append(path)
    return written


def write_plots_files(plots_dir: Path, curves: Mapping, *, evaluations: Mapping,
                      labels: Mapping[str, str]) -> list[Path]:
    """The ``dvc plots`` files: ``plots/{pr,roc}/<route>/<pair>.csv``, every method overlaid.

    ``evaluations`` (``{method: metrics.json}``) gives each pair's ``n_positive`` and
    ``n_scored`` (selected protocol) for the ROC. Earlier files under ``pr/`` and ``roc/`` are
    removed first, so no chart from another run (or the old one-file-per-method layout) stays.
    """
    for kind in ("pr", "roc"):
        if (plots_dir / kind).is_dir():
            shutil.rmtree(plots_dir / kind)
    return plots.write_overlay_plots(plots_dir, curves, counts=roc_counts(curves, evaluations),
                                     labels=labels)
