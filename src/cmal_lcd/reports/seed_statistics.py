"""Statistics over seeds: mean and a 95% confidence interval **over seeds** (Student's t on
the per-seed values: seeds are the independent repeats of a GAN training), paired differences
between two methods, and their table cells."""

from __future__ import annotations


import numpy as np
import pandas as pd
from scipy import stats

from cmal_lcd.reports.sweep_jobs import METRICS, is_plumbing_override


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
    """Mean and 95% CI over seeds of ``metric`` per route, pair, method and other override
    (run plumbing such as ``app.reuse.*`` or ``methods`` aside: :func:`is_plumbing_override`).

    Returns
    -------
    DataFrame with columns ``route, pair, method, ..., n_seeds, mean, ci_low, ci_high``.
    """
    if seed_column not in table.columns:
        raise ValueError(f"{seed_column!r}: the sweep has no such override column; sweep "
                         f"seeds with `{seed_column}=0,1,2`")
    if metric not in METRICS:
        raise ValueError(f"metric: {metric!r} is not one of {list(METRICS)}")
    keys = [c for c in table.columns
            if c not in (*METRICS, seed_column, "job") and not is_plumbing_override(c)]
    rows = []
    for group, part in table.groupby(keys, sort=True, dropna=False):
        mean, low, high = confidence_interval(part[metric].to_numpy(float))
        rows.append({**dict(zip(keys, group)), "n_seeds": int(part[seed_column].nunique()),
                     "mean": mean, "ci_low": low, "ci_high": high})
    return pd.DataFrame(rows)

#: How the intervals of proportions are shown (every metric of :data:`METRICS` is one).
CLIPPED_NOTE = ("Intervals: Student's t over seeds, clipped to [0, 100]% (a proportion cannot "
                "leave it; with 3 seeds the unclipped interval often does).")

def percent_interval(mean: float, low: float, high: float) -> str:
    """``"31.2% [25.0, 37.4]"``: a proportion's mean and interval as percentages, the interval
    clipped to [0, 100]% (:data:`CLIPPED_NOTE`)."""
    low, high = (float(np.clip(v, 0.0, 1.0)) for v in (low, high))
    return f"{100 * mean:.1f}% [{100 * low:.1f}, {100 * high:.1f}]"

def format_mean_ci(row: pd.Series) -> str:
    """``"31.2% [25.0, 37.4]"``: mean and 95% CI as percentages (:func:`percent_interval`)."""
    return percent_interval(row["mean"], row["ci_low"], row["ci_high"])

def seed_table(stats_table: pd.DataFrame) -> pd.DataFrame:
    """Table II layout: methods as rows, one column per route and pair (``route1
    foggy-rainy``), ``mean [95% CI]`` cells."""
    cells = stats_table.assign(cell=stats_table.apply(format_mean_ci, axis=1),
                               column=stats_table["route"].astype(str) + " "
                               + stats_table["pair"].astype(str))
    table = cells.pivot_table(index="method", columns="column", values="cell", aggfunc="first")
    table.columns.name = None
    return table

def paired_difference(table: pd.DataFrame, *, method: str, other: str,
                      metric: str = "recall_at_100p") -> pd.DataFrame:
    """``method - other`` per route and pair, paired by seed: mean and 95% CI over seeds.

    Returns
    -------
    DataFrame
        ``route, pair, n_seeds, mean, ci_low, ci_high, significant`` (the CI excludes 0).
    """
    rows = []
    for (route, pair), part in table.groupby(["route", "pair"], sort=False):
        wide = part.pivot_table(index="seed", columns="method", values=metric, aggfunc="first")
        if method not in wide or other not in wide:
            continue
        diff = (wide[method] - wide[other]).dropna().to_numpy(float)
        mean, low, high = confidence_interval(diff)
        rows.append({"route": route, "pair": pair, "n_seeds": len(diff), "mean": mean,
                     "ci_low": low, "ci_high": high,
                     "significant": bool(len(diff) > 1 and (low > 0 or high < 0))})
    return pd.DataFrame(rows)
