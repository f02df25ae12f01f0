"""``cmal-lcd seeds-report``: CMAL objectives (or any focus method) compared over seeds on the
validation drives, Table II with 95% CIs, paired differences and invariance, as
``README.md`` and CSVs (:func:`write_seeds_report`)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

from cmal_lcd.reports.seed_statistics import (CLIPPED_NOTE, confidence_interval, paired_difference,
                                              percent_interval, seed_statistics, seed_table)
from cmal_lcd.reports.sweep_jobs import (METRICS, collect_invariance, collect_sweep,
                                         collect_validation, copy_job_records,
                                         is_plumbing_override, jobs_and_overrides, kept_iteration,
                                         method_labels, sweep_jobs, training_processor)


def _processor_lines(sweeps: dict[str, str | Path], *, focus: str) -> list[str]:
    """Which processors trained the jobs' ``focus`` models, with how many jobs each."""
    counts: dict[str, int] = {}
    for sweep in sweeps.values():
        for job, _ in jobs_and_overrides(Path(sweep), finished=False):
            cpu = training_processor(job, focus) or "not recorded"
            counts[cpu] = counts.get(cpu, 0) + 1
    if not counts:
        return []
    listed = "; ".join(f"{cpu} ({n} job{'s' if n > 1 else ''})" for cpu, n in counts.items())
    return [f"Trained on: {listed}. Trained weights differ across processor families "
            "(`docs/reliability.md`), so these statistics describe this processor.", ""]

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

#: The targets the issues set for each focus method, on the rendered world's 6 test pairs:
#: ``above_control`` / ``at_least_sad``: pairs (of 6) where the seed mean is above the untrained
#: control (R@100P and AUC-PR) / at or above SAD (R@100P); ``above_bigan``: the mean over pairs
#: above BiGAN's; ``significantly_above``: a method the focus must beat on R@100P, paired by
#: seed (the per-seed mean over pairs, 95% Student-t interval above 0). A focus not named here
#: has no targets. cmal: the reproduction's (set before the extension); cmal_place: issue 36's.
TARGETS = {
    "cmal": {"above_control": 5, "at_least_sad": 3, "above_bigan": True},
    "cmal_place": {"at_least_sad": 4, "significantly_above": "cmal"},
}


def _share_target(got: tuple[int, int], of_six: int) -> str:
    """``got`` = (pairs meeting it, pairs): the issue's "at least k of the world's 6 pairs", as
    the same share of these pairs."""
    needed = math.ceil(of_six * got[1] / 6)
    share = "" if got[1] == 6 else f"; {of_six} of 6 on the rendered world"
    return (f"{got[0]} of {got[1]} pairs (target: at least {needed} of {got[1]}{share}): "
            f"**{'met' if got[0] >= needed else 'not met'}**.")


def _pair_mean_difference(table: pd.DataFrame, *, method: str, other: str,
                          metric: str = "recall_at_100p") -> tuple[int, float, float, float]:
    """``method - other`` of ``metric`` averaged over the pairs of each seed, then mean and 95%
    CI over seeds: ``(n_seeds, mean, low, high)``; seeds missing either method are left out."""
    wide = table.pivot_table(index=["seed", "route", "pair"], columns="method", values=metric,
                             aggfunc="first")
    diff = (wide[method] - wide[other]).dropna().groupby(level="seed").mean().to_numpy(float)
    return (len(diff), *confidence_interval(diff))


def target_lines(table: pd.DataFrame, *, focus: str = "cmal") -> list[str]:
    """``focus``'s targets (:data:`TARGETS`), checked on the seed means of one objective's
    test-route table.

    Parameters
    ----------
    table : DataFrame
        :func:`collect_sweep` rows: ``route, pair, method, seed, recall_at_100p, auc_pr``.

    Returns
    -------
    list of str
        One Markdown bullet per target, each ending in **met** or **not met**; a single bullet
        saying so when ``focus`` has no targets.
    """
    targets = TARGETS.get(focus)
    if targets is None:
        return [f"- {focus}: no issue sets a target for this method."]
    means = table.groupby(["route", "pair", "method"], sort=True)[
        ["recall_at_100p", "auc_pr"]].mean().unstack("method")
    lines = []

    def pairs_where(metric, other, *, ties=False):
        if (metric, focus) not in means or (metric, other) not in means:
            return None
        a, b = means[(metric, focus)], means[(metric, other)]
        return int(((a >= b) if ties else (a > b)).sum()), len(a)

    control = "cmal_untrained"
    for metric in ("recall_at_100p", "auc_pr") if "above_control" in targets else ():
        got = pairs_where(metric, control)
        if got:
            lines.append(f"- {focus} > {control} on {metric} (seed means): "
                         f"{_share_target(got, targets['above_control'])}")
    got = pairs_where("recall_at_100p", "sad", ties=True) if "at_least_sad" in targets else None
    if got:
        lines.append(f"- {focus} ≥ SAD on recall_at_100p (seed means): "
                     f"{_share_target(got, targets['at_least_sad'])}")
    if (targets.get("above_bigan") and ("recall_at_100p", "bigan") in means
            and ("recall_at_100p", focus) in means):
        a = float(means[("recall_at_100p", focus)].mean())
        b = float(means[("recall_at_100p", "bigan")].mean())
        lines.append(f"- {focus} > BiGAN on mean recall_at_100p: {100 * a:.1f}% vs {100 * b:.1f}%:"
                     f" **{'met' if a > b else 'not met'}**.")
    other = targets.get("significantly_above")
    if other and ("recall_at_100p", other) in means and ("recall_at_100p", focus) in means:
        n, mean, low, high = _pair_mean_difference(table, method=focus, other=other)
        met = n > 1 and low > 0
        lines.append(f"- {focus} significantly above {other} on recall_at_100p (mean over pairs "
                     f"per seed, paired over {n} seeds, 95% CI): {100 * mean:+.1f} points "
                     f"[{100 * low:+.1f}, {100 * high:+.1f}]: **{'met' if met else 'not met'}**.")
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
            if jobs_and_overrides(Path(d))}

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
