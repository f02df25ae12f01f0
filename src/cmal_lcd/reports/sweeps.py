"""Turning a Hydra sweep folder into a tidy table, seed statistics and figures.

A sweep folder (``multirun/<date>/<time>/``) holds one sub-folder per job with Hydra's
``.hydra/overrides.yaml`` and the app's flat ``metrics.json``
(``{"route/pair/method/metric": value}``). :func:`collect_sweep` makes one row per job and
metric entry; :func:`seed_statistics` gives mean and a 95% confidence interval **over seeds**
(Student's t on the per-seed values: seeds are the independent repeats of a GAN training).
"""

from __future__ import annotations

import json
import math
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


def collect_sweep(sweep_dir: str | Path, *, variant: str = "selected") -> pd.DataFrame:
    """One row per (job, route, pair, method) with the job's overrides and the five metrics.

    ``variant``: ``selected`` (the job's ``metrics.json``: each method's protocol chosen on
    validation), or another variant of the evaluate stage's files
    (``data/evaluation/<method>/metrics.json``: ``paper``, or ``strict``, the selected matches
    at ``matching.d_thresh_strict``).

    Raises
    ------
    FileNotFoundError
        When ``sweep_dir`` is not a folder, or has no job with ``.hydra/overrides.yaml`` and
        ``metrics.json``.
    """
    sweep_dir = Path(sweep_dir)
    if not sweep_dir.is_dir():
        raise FileNotFoundError(f"{sweep_dir}: no such sweep folder (a `cmal-lcd-run -m ...` "
                                f"output, e.g. multirun/<date>/<time>)")
    rows = []
    for job in sweep_jobs(sweep_dir):
        overrides = parse_overrides(yaml.safe_load((job / ".hydra/overrides.yaml").read_text())
                                    or [])
        metrics_file = job / "metrics.json"
        if not metrics_file.is_file():
            logger.warning("%s: no metrics.json (the job failed or is still running); skipped",
                           job)
            continue
        entries = (job_metrics(metrics_file) if variant == "selected"
                   else variant_metrics(job / "data" / "evaluation", variant))
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


def job_metrics(path: Path) -> dict:
    """``{(route, pair, method): {metric: value}}`` of a job's flat ``metrics.json``."""
    entries: dict = {}
    for key, value in json.loads(path.read_text()).items():
        route, pair, method, metric = key.split("/")
        entries.setdefault((route, pair, method), {})[metric] = value
    return entries


def variant_metrics(evaluation_dir: Path, variant: str) -> dict:
    """``{(route, pair, method): {metric: value}}`` of one variant of every method's
    ``<evaluation_dir>/<method>/metrics.json`` (methods without it are left out).

    Raises
    ------
    ValueError
        When no method's file holds ``variant`` (naming the folder).
    """
    entries: dict = {}
    for path in sorted(evaluation_dir.glob("*/metrics.json")):
        for route, pairs in json.loads(path.read_text()).items():
            for pair, variants in pairs.items():
                if variant in variants:
                    entries[(route, pair, path.parent.name)] = variants[variant]
    if not entries:
        raise ValueError(f"{evaluation_dir}: no method was evaluated with variant {variant!r}")
    return entries


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


#: Overrides that say how a job ran, not what it measured: which steps ran and which folders
#: were reused (``app.*``), Hydra's own settings, and which methods the job evaluated. Jobs
#: differing only in these are the same experiment (e.g. a seed taken from ``dvc repro``'s
#: outputs through ``app.reuse``, or a seed run without BiGAN), so they are pooled over seeds.
PLUMBING_PREFIXES = ("app.", "hydra.")
PLUMBING_KEYS = ("methods",)


def is_plumbing_override(column: str) -> bool:
    """Whether an override column is run plumbing (:data:`PLUMBING_PREFIXES`), not a setting."""
    return column in PLUMBING_KEYS or column.startswith(PLUMBING_PREFIXES)


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


# ---------------------------------------------------------------------------------------------
# Seed report: objectives compared on validation drives, Table II and paired tests over seeds
# ---------------------------------------------------------------------------------------------

def evaluated_test_routes(job: Path) -> bool:
    """Whether a job evaluated the test routes: its ``metrics.json`` exists and has entries (a
    job whose steps stopped at ``select_protocol`` writes an empty one)."""
    path = Path(job) / "metrics.json"
    if not path.is_file():
        return False
    try:
        return bool(json.loads(path.read_text()))
    except json.JSONDecodeError:
        return False


def sweep_jobs(sweep_dir: Path) -> list[Path]:
    """The job folders of a Hydra sweep (those with ``.hydra/overrides.yaml``), in job order:
    numbered folders by number (``2`` before ``10``), then any others by name."""
    jobs = (p.parent.parent for p in Path(sweep_dir).glob("*/.hydra/overrides.yaml"))
    return sorted(jobs, key=lambda job: (not job.name.isdigit(),
                                         int(job.name) if job.name.isdigit() else 0, job.name))


def _jobs(sweep_dir: Path, *, finished: bool = True) -> list[tuple[Path, dict[str, str]]]:
    """Jobs of a sweep and their overrides, in job order (:func:`sweep_jobs`); with
    ``finished``, only those that evaluated the test routes (:func:`evaluated_test_routes`)."""
    jobs = []
    for job in sweep_jobs(sweep_dir):
        overrides_file = job / ".hydra" / "overrides.yaml"
        if not finished or evaluated_test_routes(job):
            jobs.append((job, parse_overrides(yaml.safe_load(overrides_file.read_text()) or [])))
    return jobs


def job_setting(job: Path, key: str):
    """A dotted key of a job's composed config (``.hydra/config.yaml``, interpolations such as
    ``${models.cmal.iterations}`` resolved), or None if absent."""
    from omegaconf import OmegaConf

    path = Path(job) / ".hydra" / "config.yaml"
    if not path.is_file():
        return None
    value = OmegaConf.select(OmegaConf.load(path), key, default=None)
    return OmegaConf.to_container(value, resolve=True) if OmegaConf.is_config(value) else value


def job_models_dir(job: Path) -> Path:
    """The models folder a job used: its own, or ``app.reuse.models`` (a relative path is
    relative to the folder the job was launched from, Hydra's ``runtime.cwd``)."""
    reused = job_setting(job, "app.reuse.models")
    if reused is None:
        return Path(job) / "models"
    reused = Path(reused)
    hydra_file = Path(job) / ".hydra" / "hydra.yaml"
    if not reused.is_absolute() and hydra_file.is_file():
        cwd = (yaml.safe_load(hydra_file.read_text()) or {}).get("hydra", {}).get(
            "runtime", {}).get("cwd")
        reused = Path(cwd) / reused if cwd else reused
    return reused


def kept_iteration(job: Path, model: str) -> int | None:
    """The training iteration ``model.pt`` keeps (``models/<model>/selection.json``,
    ``select: best_validation``), or None when the job's models have no such file."""
    path = job_models_dir(job) / model / "selection.json"
    if not path.is_file():
        return None
    iteration = json.loads(path.read_text()).get("iteration")
    return None if iteration is None else int(iteration)


def training_processor(job: Path, model: str) -> str | None:
    """The processor that trained the job's ``model`` (``kernels.cpu`` of its ``model.pt``,
    own or reused), or None when there is no such file or record. Trained weights differ across
    processor families (``docs/reliability.md``)."""
    path = job_models_dir(job) / model / "model.pt"
    if not path.is_file():
        return None
    import torch

    record = torch.load(path, map_location="cpu", weights_only=True).get("kernels") or {}
    return record.get("cpu")


def _processor_lines(sweeps: dict[str, str | Path], *, focus: str) -> list[str]:
    """Which processors trained the jobs' ``focus`` models, with how many jobs each."""
    counts: dict[str, int] = {}
    for sweep in sweeps.values():
        for job, _ in _jobs(Path(sweep), finished=False):
            cpu = training_processor(job, focus) or "not recorded"
            counts[cpu] = counts.get(cpu, 0) + 1
    if not counts:
        return []
    listed = "; ".join(f"{cpu} ({n} job{'s' if n > 1 else ''})" for cpu, n in counts.items())
    return [f"Trained on: {listed}. Trained weights differ across processor families "
            "(`docs/reliability.md`), so these statistics describe this processor.", ""]


def collect_validation(sweep_dir: str | Path, *, method: str) -> pd.DataFrame:
    """One row per job: its overrides and ``method``'s validation scores under the protocol
    ``select_protocol`` chose (``data/protocol/<method>.json``): ``val_recall_at_100p``,
    ``val_auc_pr``, ``protocol``, ``finished`` (whether the job also evaluated the test routes),
    ``iterations`` (trained) and ``kept_iteration`` (the one ``model.pt`` keeps).

    A job stopped after its ``select_protocol`` step counts here: the validation score needs
    nothing later."""
    rows = []
    for job, overrides in _jobs(Path(sweep_dir), finished=False):
        path = job / "data" / "protocol" / f"{method}.json"
        if not path.is_file():
            continue
        record = json.loads(path.read_text())
        chosen = next((c for c in record.get("candidates", [])
                       if c["label"] == record["selected"]["label"]), {})
        rows.append({"job": job.name, **overrides, "method": method,
                     "finished": evaluated_test_routes(job),
                     "iterations": job_setting(job, f"models.{method}.iterations"),
                     "kept_iteration": kept_iteration(job, method),
                     "protocol": record["selected"]["label"],
                     "val_recall_at_100p": chosen.get("mean_recall_at_100p", np.nan),
                     "val_auc_pr": chosen.get("mean_auc_pr", np.nan)})
    return pd.DataFrame(rows)


def collect_invariance(sweep_dir: str | Path) -> pd.DataFrame:
    """One row per job, route and method of ``data/evaluation/invariance.json``."""
    rows = []
    for job, overrides in _jobs(Path(sweep_dir)):
        path = job / "data" / "evaluation" / "invariance.json"
        if not path.is_file():
            continue
        for route, per_method in json.loads(path.read_text()).items():
            for method, stats_ in per_method.items():
                rows.append({"job": job.name, **overrides, "route": route, "method": method,
                             **{k: v for k, v in stats_.items()
                                if isinstance(v, (int, float))}})
    return pd.DataFrame(rows)


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


def _kept_text(iteration) -> str:
    return "?" if iteration is None or pd.isna(iteration) else str(int(iteration))


def _mean_ci_text(values) -> str:
    return percent_interval(*confidence_interval(np.asarray(values, float)))


def _difference_lines(diff: pd.DataFrame, *, method: str, other: str,
                      metric: str = "recall_at_100p") -> list[str]:
    if diff.empty:
        return [f"- {method} vs {other}: no paired seeds."]
    if int(diff["n_seeds"].max()) < 2:
        cells = "; ".join(f"{r.route} {r.pair} {100 * r.mean:+.1f}" for r in diff.itertuples())
        return [f"- **{method} − {other}** ({metric} points, one seed: no interval, no test): "
                f"{cells}."]
    better = int(((diff["mean"] > 0) & diff["significant"]).sum())
    worse = int(((diff["mean"] < 0) & diff["significant"]).sum())
    # a difference of two proportions lies in [-100, +100] points: its interval is shown so
    # clipped (significance is decided on the unclipped one)
    cells = "; ".join(f"{r.route} {r.pair} {100 * r.mean:+.1f} "
                      f"[{100 * max(r.ci_low, -1.0):+.1f}, {100 * min(r.ci_high, 1.0):+.1f}]"
                      for r in diff.itertuples())
    return [f"- **{method} − {other}** ({metric} points, mean [95% CI] over "
            f"{int(diff['n_seeds'].max())} seeds): {cells}. Significantly higher on {better} "
            f"of {len(diff)} pairs, significantly lower on {worse}."]


def target_lines(table: pd.DataFrame, *, focus: str = "cmal") -> list[str]:
    """The issue's targets, checked on the seed means of one objective's test-route table.

    Parameters
    ----------
    table : DataFrame
        :func:`collect_sweep` rows: ``route, pair, method, seed, recall_at_100p, auc_pr``.

    Returns
    -------
    list of str
        Markdown bullets: ``focus`` above its untrained control (R@100P and AUC-PR, pairs),
        ``focus`` at or above SAD (R@100P, pairs), and the order ``focus`` > BiGAN on the mean.
    """
    means = table.groupby(["route", "pair", "method"], sort=True)[
        ["recall_at_100p", "auc_pr"]].mean().unstack("method")
    lines = []

    def pairs_where(metric, other, *, ties=False):
        if (metric, focus) not in means or (metric, other) not in means:
            return None
        a, b = means[(metric, focus)], means[(metric, other)]
        return int(((a >= b) if ties else (a > b)).sum()), len(a)

    def target(got, of_six: int) -> str:
        """The issue's "at least k of the world's 6 pairs", as the same share of these."""
        needed = math.ceil(of_six * got[1] / 6)
        share = "" if got[1] == 6 else f"; {of_six} of 6 on the rendered world"
        return (f"{got[0]} of {got[1]} pairs (target: at least {needed} of {got[1]}{share}): "
                f"**{'met' if got[0] >= needed else 'not met'}**.")

    control = "cmal_untrained"
    for metric in ("recall_at_100p", "auc_pr"):
        got = pairs_where(metric, control)
        if got:
            lines.append(f"- {focus} > {control} on {metric} (seed means): {target(got, 5)}")
    got = pairs_where("recall_at_100p", "sad", ties=True)
    if got:
        lines.append(f"- {focus} ≥ SAD on recall_at_100p (seed means): {target(got, 3)}")
    if ("recall_at_100p", "bigan") in means and ("recall_at_100p", focus) in means:
        a = float(means[("recall_at_100p", focus)].mean())
        b = float(means[("recall_at_100p", "bigan")].mean())
        lines.append(f"- {focus} > BiGAN on mean recall_at_100p: {100 * a:.1f}% vs {100 * b:.1f}%:"
                     f" **{'met' if a > b else 'not met'}**.")
    return lines


def _objectives_validation(sweeps: dict[str, str | Path], *, focus: str) -> pd.DataFrame:
    """:func:`collect_validation` of ``focus`` in every sweep, stacked.

    Returns
    -------
    DataFrame
        One row per job that ran ``select_protocol``: ``job``, the job's overrides (``seed``,
        ...), ``method, finished, iterations, kept_iteration, protocol, val_recall_at_100p,
        val_auc_pr`` and ``objective`` (the sweep's key in ``sweeps``).
    """
    return pd.concat([collect_validation(d, method=focus).assign(objective=name)
                      for name, d in sweeps.items()], ignore_index=True)


def _objectives_test_tables(sweeps: dict[str, str | Path], *,
                            variant: str = "selected") -> dict[str, pd.DataFrame]:
    """:func:`collect_sweep` of every sweep with a job that evaluated the test routes
    (``variant``: see :func:`collect_sweep`).

    Returns
    -------
    dict
        ``{objective name: DataFrame}`` in the order of ``sweeps``; one row per (job, route,
        pair, method): ``job``, the job's overrides (``seed``, ...), ``route, pair, method`` and
        the :data:`METRICS` columns.
    """
    return {name: collect_sweep(d, variant=variant) for name, d in sweeps.items()
            if _jobs(Path(d))}


def _objectives_invariance(sweeps: dict[str, str | Path]) -> pd.DataFrame:
    """:func:`collect_invariance` of every sweep, stacked.

    Returns
    -------
    DataFrame
        One row per job, route and method: ``job``, the job's overrides, ``route, method``,
        the numeric entries of ``invariance.json`` (``ratio``, ``single_frame_recall_at_1``,
        ...) and ``objective``; only ``objective`` when no job has ``invariance.json``.
    """
    return pd.concat([collect_invariance(d).assign(objective=name)
                      for name, d in sweeps.items()], ignore_index=True)


#: The files of a job that the seed report reads (beside the trained weights), copied under
#: ``jobs/<sweep name>/<job>/`` so that the numbers travel with their inputs and configs.
JOB_RECORDS = (".hydra/overrides.yaml", ".hydra/config.yaml", "metrics.json",
               "data/protocol/*.json", "data/evaluation/invariance.json",
               "models/*/selection.json", "models/*/train_log.csv")


def copy_job_records(sweeps: dict[str, str | Path], out_dir: Path) -> list[Path]:
    """Copy each job's :data:`JOB_RECORDS` to ``out_dir/jobs/<sweep name>/<job>/`` (the same
    layout, so ``cmal-lcd seeds-report NAME=out_dir/jobs/NAME`` reads them again; only the
    processor line needs the weights). Returns the copied files.

    How a job was run is left out, since it names folders of the machine that ran it: the
    plumbing overrides (:func:`is_plumbing_override`: ``app.*``, ``hydra.*``, ``methods``) and
    the ``app`` node of its config (which ``params.yaml`` never has either)."""
    copied = []
    for name, sweep in sweeps.items():
        for job in sweep_jobs(Path(sweep)):
            for pattern in JOB_RECORDS:
                for source in sorted(job.glob(pattern)):
                    target = out_dir / "jobs" / name / job.name / source.relative_to(job)
                    target.parent.mkdir(parents=True, exist_ok=True)
                    _copy_record(source, target)
                    copied.append(target)
    return copied


def _copy_record(source: Path, target: Path) -> None:
    """Copy one job record; a Hydra overrides or config file without the run's plumbing."""
    import shutil

    if source.parent.name != ".hydra":
        shutil.copyfile(source, target)
        return
    data = yaml.safe_load(source.read_text())
    if source.name == "overrides.yaml":
        data = [o for o in data or [] if not is_plumbing_override(str(o).partition("=")[0])]
    elif isinstance(data, dict):
        data.pop("app", None)
    target.write_text(yaml.safe_dump(data, sort_keys=False))


def method_labels(sweeps: dict[str, str | Path]) -> dict[str, dict[str, list[str]]]:
    """``{method: {row label: [sweep names]}}`` from the jobs' ``data/features/<method>/info.json``
    (the first job of each sweep that has one; a trained model labels its own codes with its
    objective, so one method key can be two rows when the sweeps differ in objective)."""
    labels: dict[str, dict[str, list[str]]] = {}
    for name, sweep in sweeps.items():
        seen: set[str] = set()
        for job in sweep_jobs(Path(sweep)):
            for info in sorted(job.glob("data/features/*/info.json")):
                label = json.loads(info.read_text()).get("label")
                if label and info.parent.name not in seen:
                    seen.add(info.parent.name)
                    labels.setdefault(info.parent.name, {}).setdefault(str(label), []).append(name)
    return labels


def _row_lines(sweeps: dict[str, str | Path]) -> list[str]:
    """What each row of the tables is: its method key and its label (per sweep, when the
    sweeps label it differently)."""
    labels = method_labels(sweeps)
    if not labels:
        return []

    def described(by_label: dict[str, list[str]]) -> str:
        if len(by_label) == 1:
            return next(iter(by_label))
        return "; ".join(f"{label} (sweep{'s' if len(names) > 1 else ''} "
                         f"{', '.join(f'`{n}`' for n in names)})"
                         for label, names in by_label.items())

    return (["Rows (method key: what it is):", ""]
            + [f"- `{method}`: {described(by_label)}" for method, by_label in labels.items()]
            + [""])


def _without_plumbing(table: pd.DataFrame) -> pd.DataFrame:
    """``table`` without its run-plumbing override columns (:func:`is_plumbing_override`),
    which name folders of the machine that ran the sweep."""
    return table[[c for c in table.columns if not is_plumbing_override(str(c))]]


def _report_header_lines(sweeps: dict[str, str | Path], *, focus: str = "cmal") -> list[str]:
    """The README's title and the sweeps its numbers come from."""
    return [f"# {focus} over seeds: validation choices, Table II with 95% CIs", "",
            "Produced by `cmal-lcd seeds-report` from the Hydra sweeps "
            + ", ".join(f"`{name}` ({sum(1 for _ in sweep_jobs(Path(d)))} jobs; each job's "
                        f"configuration, overrides, metrics, protocols and training logs are "
                        f"copied into `jobs/{name}/`)" for name, d in sweeps.items())
            + ". Each job trains the learned models with its seed on the same dataset "
            "(`app.reuse.dataset`). " + CLIPPED_NOTE + " The unclipped bounds are in the "
            "CSV files beside this one.", ""]


def _variant_lines(sweeps: dict[str, str | Path], variant: str) -> list[str]:
    """Which test metrics the tables hold, when not each method's selected protocol at
    ``matching.d_thresh``: for ``strict``, the tolerance (from the first job's config)."""
    if variant == "selected":
        return []
    if variant != "strict":
        return [f"**Test tables: the `{variant}` variant of the evaluate stage.**", ""]
    first = next(iter(sweep_jobs(Path(next(iter(sweeps.values()))))))
    matching = (yaml.safe_load((first / ".hydra" / "config.yaml").read_text()) or {}).get(
        "matching", {})
    return [f"**Test tables at the strict tolerance**: the same matches as each job's main "
            f"tables (protocol chosen on validation, tolerance ±{matching.get('d_thresh')} "
            f"frames), counted correct only within ±{matching.get('d_thresh_strict')} "
            f"frame(s) of the true place (`matching.d_thresh_strict`, fixed before the runs). "
            f"The validation columns are those of the main tolerance.", ""]


def _validation_means(validation: pd.DataFrame) -> dict[str, float]:
    """Mean validation R@100P per objective, ``{objective: mean}`` in order of appearance.

    Parameters
    ----------
    validation : DataFrame
        :func:`_objectives_validation` rows (``objective, val_recall_at_100p``).
    """
    return {name: float(part["val_recall_at_100p"].mean())
            for name, part in validation.groupby("objective", sort=False)}


def _objective_table_lines(validation: pd.DataFrame, *, focus: str) -> list[str]:
    """The heading of the objective comparison and its Markdown table, one row per objective.

    Parameters
    ----------
    validation : DataFrame
        :func:`_objectives_validation` rows (``objective, seed, iterations, kept_iteration,
        protocol, val_recall_at_100p, val_auc_pr``).
    """
    lines = ["## Which objective: validation drives only", "",
             f"{focus} mean recall@100%P and AUC-PR over the validation pairs, under the "
             "protocol `select_protocol` chose for each job:", "",
             "| objective | seeds | iterations | kept (per seed) | validation R@100P | "
             "validation AUC-PR | protocols chosen |",
             "|:--|--:|--:|:--|--:|--:|:--|"]
    for name, part in validation.groupby("objective", sort=False):
        iterations = ", ".join(str(i) for i in sorted(set(part["iterations"].dropna())))
        kept = ", ".join(f"seed {row.seed}: {_kept_text(row.kept_iteration)}"
                         for row in part.sort_values("seed").itertuples()) \
            if "kept_iteration" in part else "?"
        lines.append(f"| {name} | {len(part)} | {iterations or '?'} | {kept} | "
                     f"{_mean_ci_text(part['val_recall_at_100p'])} | "
                     f"{_mean_ci_text(part['val_auc_pr'])} | "
                     f"{'; '.join(sorted(set(part['protocol'])))} |")
    return lines


def _training_length_lines(validation: pd.DataFrame) -> list[str]:
    """A warning when the objectives were trained for different numbers of iterations (from
    the ``objective, iterations`` columns of :func:`_objectives_validation`), else nothing."""
    lengths = validation.groupby("objective", sort=False)["iterations"].apply(
        lambda v: tuple(sorted(set(v.dropna())))) if "iterations" in validation else None
    if lengths is not None and len(set(lengths)) > 1:
        return ["", "The objectives were trained for different numbers of iterations ("
                + ", ".join(f"{name}: {', '.join(map(str, its)) or '?'}"
                            for name, its in lengths.items())
                + "): the comparison below mixes the objective with the training length."]
    return []


def _kept_note_lines() -> list[str]:
    """What the table's "kept" column means and why its validation scores are optimistic."""
    return ["", "\"kept\": the training iteration each job's `model.pt` keeps "
            "(`select: best_validation`: the validated iteration with the best validation "
            "R@100P, never iteration 0; `models/<name>/selection.json`; `?`: the job's models "
            "predate selection). The validation scores above are those of the kept weights, "
            "on the same validation drives that chose them, so they are optimistic for both "
            "objectives alike; the test tables below are not."]


def _winner_lines(means: dict[str, float], *, default: str) -> list[str]:
    """The validation winner (highest of :func:`_validation_means`) against ``default``."""
    winner = max(means, key=means.get) if means else None
    return ["", f"Validation winner (mean R@100P): **{winner}**; the configuration's default "
            f"objective is **{default}**"
            + ("." if winner == default else " (not the validation winner: see the note "
                                              "below).")]


def _paired_validation_lines(validation: pd.DataFrame, means: dict[str, float]) -> list[str]:
    """With exactly two objectives (the keys of ``means``), their validation R@100P difference
    paired by seed, mean [95% CI] (``objective, seed, val_recall_at_100p`` of ``validation``);
    otherwise nothing."""
    if len(means) == 2:
        a, b = list(means)
        pa = validation[validation["objective"] == a].set_index("seed")["val_recall_at_100p"]
        pb = validation[validation["objective"] == b].set_index("seed")["val_recall_at_100p"]
        diff = (pa - pb).dropna().to_numpy(float)
        mean, low, high = confidence_interval(diff)
        verdict = ("one paired seed: no test" if len(diff) < 2 else
                   "significant at 95%" if low > 0 or high < 0 else "not significant at 95%")
        return [(f"Paired by seed, {a} − {b}: {100 * mean:+.1f} points [{100 * low:+.1f}, "
                 f"{100 * high:+.1f}] over {len(diff)} seed(s) ({verdict}).")]
    return []


def _few_seeds_lines(validation: pd.DataFrame) -> list[str]:
    """A caution naming the objectives with fewer than 3 seeds (``objective, seed`` columns of
    :func:`_objectives_validation`), else nothing."""
    few = {name: int(part["seed"].nunique()) for name, part in validation.groupby("objective")
           if part["seed"].nunique() < 3}
    if few:
        return ["Fewer than 3 seeds finished for: " + ", ".join(
            f"{name} ({n})" for name, n in few.items()) + "; treat these comparisons as "
            "indications, not verdicts."]
    return []


def _stopped_jobs_lines(validation: pd.DataFrame) -> list[str]:
    """The jobs that stopped after their validation step (``finished`` false in
    :func:`_objectives_validation`), else nothing."""
    if "finished" in validation and not validation["finished"].all():
        stopped = validation[~validation["finished"].astype(bool)]
        return ["Stopped after the validation step (counted above, absent from the test "
                "tables below): " + ", ".join(
                    f"{row.objective} seed {row.seed}" for row in stopped.itertuples())
                + "."]
    return []


def _objective_choice_lines(validation: pd.DataFrame, *, default: str,
                            focus: str) -> list[str]:
    """The section "Which objective": the objectives compared on the validation drives only.

    Parameters
    ----------
    validation : DataFrame
        :func:`_objectives_validation` rows.
    """
    means = _validation_means(validation)
    compared = len(means) > 1  # one sweep: nothing to choose between
    return (_objective_table_lines(validation, focus=focus)
            + _training_length_lines(validation)
            + _kept_note_lines()
            + (_winner_lines(means, default=default) if compared else [])
            + (_paired_validation_lines(validation, means) if compared else [])
            + _few_seeds_lines(validation)
            + _stopped_jobs_lines(validation))


def _validation_only_lines(sweeps: dict[str, str | Path],
                           tests: dict[str, pd.DataFrame]) -> list[str]:
    """The objectives of ``sweeps`` with no test-route table in ``tests``, else nothing."""
    validation_only = [name for name in sweeps if name not in tests]
    if validation_only:
        return ["", "Validation only (no job of these sweeps evaluated the test routes): "
                + ", ".join(f"`{name}`" for name in validation_only) + "."]
    return []


def _method_difference_lines(table: pd.DataFrame, *, focus: str) -> list[str]:
    """``focus`` minus every other method of ``table`` (in the table's order), paired by seed
    on recall_at_100p then AUC-PR (:func:`paired_difference`).

    Parameters
    ----------
    table : DataFrame
        :func:`collect_sweep` rows: ``route, pair, method, seed, recall_at_100p, auc_pr``.
    """
    lines = []
    methods = list(dict.fromkeys(table["method"]))
    for other in methods:
        if focus in methods and other != focus:
            for metric in ("recall_at_100p", "auc_pr"):
                lines += _difference_lines(paired_difference(table, method=focus, other=other,
                                                             metric=metric),
                                           method=focus, other=other, metric=metric)
    return lines


def _test_route_lines(name: str, table: pd.DataFrame, statistics: pd.DataFrame, *,
                      focus: str) -> list[str]:
    """The section on one objective's test routes: Table II (recall@100%P and AUC-PR), the
    targets and the paired differences.

    Parameters
    ----------
    table : DataFrame
        :func:`collect_sweep` rows of the objective's sweep.
    statistics : DataFrame
        :func:`seed_statistics` of ``table`` (recall_at_100p): ``route, pair, method, ...,
        n_seeds, mean, ci_low, ci_high``.
    """
    return (["", f"## Test routes, objective `{name}`: Table II, recall@100%P mean [95% CI]",
             "", seed_table(statistics).to_markdown(), "",
             "AUC-PR mean [95% CI]:", "",
             seed_table(seed_statistics(table, metric="auc_pr")).to_markdown(), "",
             "Targets (seed means):", ""]
            + target_lines(table, focus=focus) + ["",
              "Paired differences (positive = the first method higher):", ""]
            + _method_difference_lines(table, focus=focus))


def _invariance_lines(inv: pd.DataFrame) -> list[str]:
    """One objective's invariance table, mean [95% CI] over seeds per route and method, or
    nothing when it has no ``ratio``.

    Parameters
    ----------
    inv : DataFrame
        :func:`_objectives_invariance` rows of the objective (``route, method, ratio,
        single_frame_recall_at_1``).
    """
    if not inv.empty and "ratio" in inv:
        lines = ["", "Invariance across weathers (same-place / other-place difference after "
                 "each method's normalisation; lower = more invariant), mean [95% CI] over "
                 "seeds:", "", "| route | method | ratio | single-frame r@1 |",
                 "|:--|:--|--:|--:|"]
        for (route, method), part in inv.groupby(["route", "method"], sort=True):
            m, lo, hi = confidence_interval(part["ratio"].to_numpy(float))
            lines.append(f"| {route} | {method} | {m:.3f} [{lo:.3f}, {hi:.3f}] | "
                         f"{_mean_ci_text(part['single_frame_recall_at_1'])} |")
        return lines
    return []


#: What ``seeds-report`` writes into its ``--out`` folder (:func:`cmal_lcd.io.check_output_folder`).
SEEDS_REPORT_OUTPUTS = ("README.md", "validation.csv", "invariance.csv", "table2_*.csv", "jobs/")


def write_seeds_report(sweeps: dict[str, str | Path], out_dir: str | Path, *,
                       default: str, focus: str = "cmal", variant: str = "selected") -> Path:
    """``out_dir/README.md`` and CSVs comparing CMAL objectives over seeds.

    Writes ``validation.csv`` (:func:`_objectives_validation`), ``invariance.csv``
    (:func:`_objectives_invariance`), ``table2_<objective>.csv`` (:func:`seed_statistics`) for
    each objective with test-route results, the job records (:func:`copy_job_records`), then
    ``README.md``: old or new as a whole (:func:`cmal_lcd.io.staged_output_folder`; a folder
    holding other files is refused).

    Parameters
    ----------
    sweeps : dict
        ``{objective name: sweep folder}``; every sweep has a ``seed`` override.
    default : str
        The objective the configuration uses by default (stated, and checked to be the
        validation winner in the text).
    focus : str
        The method whose objectives are compared (``cmal``).
    variant : str
        Which test metrics the tables hold (:func:`collect_sweep`): ``selected``, or e.g.
        ``strict`` (stated under the title).
    """
    from cmal_lcd.io import atomic_write_text, staged_output_folder

    out_dir = Path(out_dir)
    validation = _objectives_validation(sweeps, focus=focus)
    tests = _objectives_test_tables(sweeps, variant=variant)
    invariance = _objectives_invariance(sweeps)
    lines = (_report_header_lines(sweeps, focus=focus) + _variant_lines(sweeps, variant)
             + _row_lines(sweeps)
             + _processor_lines(sweeps, focus=focus)
             + _objective_choice_lines(validation, default=default, focus=focus)
             + _validation_only_lines(sweeps, tests))
    with staged_output_folder(out_dir, SEEDS_REPORT_OUTPUTS, command="seeds-report",
                              inputs=tuple(sweeps.values())) as staging:
        atomic_write_text(staging / "validation.csv",
                          _without_plumbing(validation).to_csv(index=False))
        atomic_write_text(staging / "invariance.csv",
                          _without_plumbing(invariance).to_csv(index=False))
        copy_job_records(sweeps, staging)
        for name, table in tests.items():
            statistics = seed_statistics(table)
            atomic_write_text(staging / f"table2_{name}.csv", statistics.to_csv(index=False))
            lines += _test_route_lines(name, table, statistics, focus=focus)
            lines += _invariance_lines(invariance[invariance["objective"] == name])
        atomic_write_text(staging / "README.md", "\n".join(lines) + "\n")
    return out_dir / "README.md"
