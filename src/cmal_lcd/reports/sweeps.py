"""Turning a Hydra sweep folder into a tidy table, seed statistics and figures.

A sweep folder (``multirun/<date>/<time>/``) holds one sub-folder per job with Hydra's
``.hydra/overrides.yaml`` and the app's flat ``metrics.json``
(``{"route/pair/method/metric": value}``). :func:`collect_sweep` makes one row per job and
metric entry; :func:`seed_statistics` gives mean and a 95% confidence interval **over seeds**
(Student's t on the per-seed values: seeds are the independent repeats of a GAN training).
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
import pandas as pd
import yaml
from scipy import stats

logger = logging.getLogger(__name__)

METRICS = ("auc_pr", "auc_roc", "recall_at_100p", "recall_at_1", "single_frame_recall_at_1")


def parse_overrides(overrides: list[str]) -> dict[str, str]:
    """``["seed=1", "matching.ds=5"]`` -> ``{"seed": "1", "matching.ds": "5"}``."""
    parsed = {}
    for item in overrides:
        key, sep, value = item.partition("=")
        if not sep:
            raise ValueError(f"override {item!r}: expected key=value")
        parsed[key.lstrip("+~")] = value
    return parsed


def collect_sweep(sweep_dir: str | Path) -> pd.DataFrame:
    """One row per (job, route, pair, method) with the job's overrides and the five metrics.

    Raises
    ------
    FileNotFoundError
        When ``sweep_dir`` has no job with ``.hydra/overrides.yaml`` and ``metrics.json``.
    """
    sweep_dir = Path(sweep_dir)
    rows = []
    jobs = sorted((p.parent.parent for p in sweep_dir.glob("*/.hydra/overrides.yaml")),
                  key=lambda job: (not job.name.isdigit(), int(job.name) if job.name.isdigit()
                                   else 0, job.name))
    for job in jobs:
        overrides = parse_overrides(yaml.safe_load((job / ".hydra/overrides.yaml").read_text())
                                    or [])
        metrics_file = job / "metrics.json"
        if not metrics_file.is_file():
            logger.warning("%s: no metrics.json (the job failed or is still running); skipped",
                           job)
            continue
        entries: dict = {}
        for key, value in json.loads(metrics_file.read_text()).items():
            route, pair, method, metric = key.split("/")
            entries.setdefault((route, pair, method), {})[metric] = value
        for (route, pair, method), values in entries.items():
            rows.append({"job": job.name, **overrides, "route": route, "pair": pair,
                         "method": method, **{m: values.get(m) for m in METRICS}})
    if not rows:
        raise FileNotFoundError(f"{sweep_dir}: no finished job (a sub-folder with "
                                ".hydra/overrides.yaml and metrics.json)")
    table = pd.DataFrame(rows)
    for column in table.columns:
        if column not in METRICS and column not in ("route", "pair", "method"):
            converted = pd.to_numeric(table[column], errors="coerce")
            if converted.notna().all():
                table[column] = converted
    return table


def confidence_interval(values: np.ndarray, *, level: float = 0.95) -> tuple[float, float, float]:
    """Mean and the Student-t confidence interval of the mean of ``values`` (1-D).

    With a single value the interval is that value (no spread can be estimated).
    """
    values = np.asarray(values, dtype=float)
    values = values[np.isfinite(values)]
    if len(values) == 0:
        return float("nan"), float("nan"), float("nan")
    mean = float(values.mean())
    if len(values) == 1:
        return mean, mean, mean
    half = float(stats.t.ppf(0.5 + level / 2, len(values) - 1)
                 * values.std(ddof=1) / np.sqrt(len(values)))
    return mean, mean - half, mean + half


def seed_statistics(table: pd.DataFrame, *, metric: str = "recall_at_100p",
                    seed_column: str = "seed") -> pd.DataFrame:
    """Mean and 95% CI over seeds of ``metric`` per route, pair, method and other override.

    Returns
    -------
    DataFrame with columns ``route, pair, method, ..., n_seeds, mean, ci_low, ci_high``.
    """
    if seed_column not in table.columns:
        raise ValueError(f"{seed_column!r}: the sweep has no such override column; sweep "
                         f"seeds with `{seed_column}=0,1,2`")
    if metric not in METRICS:
        raise ValueError(f"metric: {metric!r} is not one of {list(METRICS)}")
    keys = [c for c in table.columns if c not in (*METRICS, seed_column, "job")]
    rows = []
    for group, part in table.groupby(keys, sort=True, dropna=False):
        mean, low, high = confidence_interval(part[metric].to_numpy(float))
        rows.append({**dict(zip(keys, group)), "n_seeds": int(part[seed_column].nunique()),
                     "mean": mean, "ci_low": low, "ci_high": high})
    return pd.DataFrame(rows)


def format_mean_ci(row: pd.Series) -> str:
    """``"31.2% [25.0, 37.4]"``: mean and 95% CI as percentages."""
    return f"{100 * row['mean']:.1f}% [{100 * row['ci_low']:.1f}, {100 * row['ci_high']:.1f}]"


def seed_table(stats_table: pd.DataFrame) -> pd.DataFrame:
    """Table II layout: methods as rows, (route, pair) as columns, ``mean [95% CI]`` cells."""
    cells = stats_table.assign(cell=stats_table.apply(format_mean_ci, axis=1))
    return cells.pivot_table(index="method", columns=["route", "pair"], values="cell",
                             aggfunc="first")


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


def aggregate_sweep(sweep_dir: str | Path, out_dir: str | Path) -> Path:
    """Write ``results.csv``, per-parameter figures and (with seeds) ``table2_seeds.{md,csv}``
    for a sweep folder into ``out_dir`` (e.g. ``reports/sweeps/<name>``)."""
    from cmal_lcd.io import atomic_write_text

    out_dir = Path(out_dir)
    table = collect_sweep(sweep_dir)
    atomic_write_text(out_dir / "results.csv", table.to_csv(index=False))
    swept = [c for c in table.columns
             if c not in (*METRICS, "job", "route", "pair", "method")]
    for parameter in swept:
        if parameter != "seed" and pd.api.types.is_numeric_dtype(table[parameter]):
            plot_metric_against(table, parameter,
                                out_dir / f"recall_at_100p_vs_{figure_stem(parameter)}")
    if "seed" in table.columns:
        statistics = seed_statistics(table)
        atomic_write_text(out_dir / "table2_seeds.csv", statistics.to_csv(index=False))
        header = ("Recall at 100% precision: mean over seeds with a 95% confidence interval "
                  "(Student's t over seeds; n_seeds per cell in table2_seeds.csv).\n\n")
        atomic_write_text(out_dir / "table2_seeds.md",
                          header + seed_table(statistics).to_markdown() + "\n")
    return out_dir
