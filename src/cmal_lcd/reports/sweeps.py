"""``cmal-lcd aggregate``: a Hydra sweep folder -> ``results.csv``, a figure against each swept
number and, when seeds were swept, Table II with mean and 95% CI over seeds
(:mod:`cmal_lcd.reports.sweep_jobs` reads the folder, :mod:`cmal_lcd.reports.seed_statistics`
computes the intervals)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from cmal_lcd.reports.seed_statistics import seed_statistics, seed_table
from cmal_lcd.reports.sweep_jobs import METRICS, collect_sweep


def plot_metric_against(table: pd.DataFrame, parameter: str, path: Path, *,
                        metric: str = "recall_at_100p") -> None:
    """Line plot of ``metric`` (mean over jobs, routes and pairs)
    against a swept ``parameter``, one line per method; ``path`` + ``.png`` and ``.pdf``.

    The band is the standard error of the mean over the jobs, routes and pairs at one value.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5, 3.5))
    for method, part in table.groupby("method", sort=True):
        summary = part.groupby(parameter)[metric].agg(["mean", "std", "count"]).sort_index()
        ax.plot(summary.index, summary["mean"], marker="o", label=method)
        if (summary["count"] > 1).any():
            err = summary["std"].fillna(0) / np.sqrt(summary["count"])
            ax.fill_between(summary.index, summary["mean"] - err, summary["mean"] + err,
                            alpha=0.2)
    ax.set_xlabel(parameter)
    ax.set_ylabel(f"{metric} (mean over routes and pairs)")
    ax.set_ylim(0, 1)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path.parent / f"{path.name}.png", dpi=150)
    fig.savefig(path.parent / f"{path.name}.pdf", metadata={"CreationDate": None})
    plt.close(fig)

def figure_stem(parameter: str) -> str:
    """A file-name-safe form of an override key: ``matching.ds`` -> ``matching-ds``."""
    return "".join(c if c.isalnum() or c in "_-" else "-" for c in parameter)

#: What ``aggregate`` writes into its ``--out`` folder (:func:`cmal_lcd.io.check_output_folder`).
AGGREGATE_OUTPUTS = ("results.csv", "recall_at_100p_vs_*.png", "recall_at_100p_vs_*.pdf",
                     "table2_seeds.csv", "table2_seeds.md")

def aggregate_sweep(sweep_dir: str | Path, out_dir: str | Path) -> Path:
    """Write ``results.csv``, per-parameter figures and (with seeds) ``table2_seeds.{md,csv}``
    for a sweep folder into ``out_dir`` (e.g. ``reports/sweeps/<name>``), old or new as a whole
    (:func:`cmal_lcd.io.staged_output_folder`: a folder holding other files is refused)."""
    from cmal_lcd.io import atomic_write_text, staged_output_folder

    out_dir = Path(out_dir)
    table = collect_sweep(sweep_dir)
    with staged_output_folder(out_dir, AGGREGATE_OUTPUTS, command="aggregate",
                              inputs=(sweep_dir,)) as staging:
        atomic_write_text(staging / "results.csv", table.to_csv(index=False))
        swept = [c for c in table.columns
                 if c not in (*METRICS, "job", "route", "pair", "method")]
        for parameter in swept:
            # a figure against every numeric override that varies (one held for every job,
            # like runtime.threads=1, has nothing to plot against)
            if (parameter != "seed" and pd.api.types.is_numeric_dtype(table[parameter])
                    and table[parameter].nunique() > 1):
                plot_metric_against(table, parameter,
                                    staging / f"recall_at_100p_vs_{figure_stem(parameter)}")
        if "seed" in table.columns:
            statistics = seed_statistics(table)
            atomic_write_text(staging / "table2_seeds.csv", statistics.to_csv(index=False))
            header = ("Recall at 100% precision: mean over seeds with a 95% confidence interval "
                      "(Student's t over seeds, clipped to [0, 100]%; n_seeds per cell and the "
                      "unclipped bounds in table2_seeds.csv).\n\n")
            atomic_write_text(staging / "table2_seeds.md",
                              header + seed_table(statistics).to_markdown() + "\n")
    return out_dir
