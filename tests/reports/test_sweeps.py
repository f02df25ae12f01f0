"""A Hydra sweep folder becomes a tidy table, seed statistics and figures.

The sweep folders here are written by hand in the layout the app produces: one sub-folder per
job with ``.hydra/overrides.yaml`` and a flat ``metrics.json`` (``route/pair/method/metric``).
"""

from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import pytest
import yaml

from cmal_lcd.reports.seed_statistics import (confidence_interval, format_mean_ci, seed_statistics,
                                             seed_table)
from cmal_lcd.reports.sweep_jobs import METRICS, collect_sweep, parse_overrides
from cmal_lcd.reports.sweeps import aggregate_sweep, figure_stem

#: Two-sided 95% Student t quantiles (statistical tables): df -> t_{0.975, df}.
T_975 = {1: 12.706204736, 2: 4.302652730, 4: 2.776445105}


def write_job(sweep, name, overrides, values, *, finished=True):
    """One job folder; ``values`` maps (route, pair, method) to recall at 100% precision."""
    job = sweep / name
    (job / ".hydra").mkdir(parents=True)
    (job / ".hydra" / "overrides.yaml").write_text(yaml.safe_dump(overrides))
    if finished:
        flat = {}
        for (route, pair, method), value in values.items():
            for metric in METRICS:
                flat[f"{route}/{pair}/{method}/{metric}"] = value
            flat[f"{route}/{pair}/{method}/n_query"] = 50
        (job / "metrics.json").write_text(json.dumps(flat))
    return job


@pytest.fixture
def seed_sweep(tmp_path):
    """3 seeds x 2 values of ds, two methods on one route/pair; value = f(seed, ds, method)."""
    sweep = tmp_path / "multirun"
    n = 0
    for ds in (5, 10):
        for seed in (0, 1, 2):
            values = {("r1", "a-b", "cmal"): 0.1 * (seed + 1) + ds / 100,
                      ("r1", "a-b", "sad"): 0.5}
            write_job(sweep, str(n), [f"seed={seed}", f"matching.ds={ds}"], values)
            n += 1
    return sweep


def test_parse_overrides_splits_at_the_first_equals_sign():
    assert parse_overrides(["seed=1", "+model_only=cmal", "methods=[sad,cmal]", "a.b=x=y"]) == {
        "seed": "1", "model_only": "cmal", "methods": "[sad,cmal]", "a.b": "x=y"}
    with pytest.raises(ValueError, match="noequals"):
        parse_overrides(["noequals"])


def test_collect_sweep_makes_one_row_per_job_route_pair_method(seed_sweep):
    table = collect_sweep(seed_sweep)
    assert len(table) == 6 * 2
    assert set(table.columns) >= {"job", "seed", "matching.ds", "route", "pair", "method",
                                  *METRICS}
    assert "n_query" not in table.columns
    assert pd.api.types.is_integer_dtype(table["seed"])
    assert pd.api.types.is_integer_dtype(table["matching.ds"])
    row = table[(table["job"] == 4) & (table["method"] == "cmal")].iloc[0]
    assert (row["seed"], row["matching.ds"]) == (1, 10)
    assert row["recall_at_100p"] == pytest.approx(0.2 + 0.1)


def test_collect_sweep_orders_jobs_numerically(tmp_path):
    for i in (2, 10, 1):
        write_job(tmp_path, str(i), [f"seed={i}"], {("r", "p", "m"): 0.5})
    assert list(collect_sweep(tmp_path)["job"]) == [1, 2, 10]


def test_every_reader_takes_a_sweeps_jobs_in_numeric_order(tmp_path):
    """Job 10 after job 2 (sorting names as text put it first) in the validation rows too."""
    from cmal_lcd.reports.sweep_jobs import collect_validation, sweep_jobs

    for i in (2, 10, 1):
        job = write_job(tmp_path, str(i), [f"seed={i}"], {("r", "p", "cmal"): 0.5})
        (job / "data" / "protocol").mkdir(parents=True)
        (job / "data" / "protocol" / "cmal.json").write_text(json.dumps(
            {"selected": {"label": "x"}, "candidates": [{"label": "x"}]}))
    (tmp_path / "notes").mkdir()  # not a job: no .hydra/overrides.yaml
    assert [j.name for j in sweep_jobs(tmp_path)] == ["1", "2", "10"]
    assert list(collect_validation(tmp_path, method="cmal")["job"]) == ["1", "2", "10"]


def test_unfinished_jobs_are_skipped_and_an_empty_sweep_is_an_error(tmp_path):
    write_job(tmp_path, "0", ["seed=0"], {("r", "p", "m"): 0.5})
    write_job(tmp_path, "1", ["seed=1"], {}, finished=False)
    assert list(collect_sweep(tmp_path)["seed"]) == [0]
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(FileNotFoundError, match="empty"):
        collect_sweep(empty)


def test_non_numeric_overrides_stay_strings(tmp_path):
    write_job(tmp_path, "0", ["methods=[sad,cmal]", "seed=0"], {("r", "p", "cmal"): 0.5})
    write_job(tmp_path, "1", ["methods=[sad,bigan]", "seed=0"], {("r", "p", "bigan"): 0.5})
    table = collect_sweep(tmp_path)
    assert list(table["methods"]) == ["[sad,cmal]", "[sad,bigan]"]


@pytest.mark.parametrize("values", [[1.0, 2.0, 3.0], [0.2, 0.4], [0.1, 0.5, 0.3, 0.9, 0.7]])
def test_confidence_interval_is_the_student_t_interval_of_the_mean(values):
    mean, low, high = confidence_interval(np.array(values))
    n = len(values)
    half = T_975[n - 1] * np.std(values, ddof=1) / math.sqrt(n)
    assert mean == pytest.approx(np.mean(values))
    assert (low, high) == (pytest.approx(mean - half), pytest.approx(mean + half))


def test_confidence_interval_of_one_value_is_that_value_and_nan_values_are_ignored():
    assert confidence_interval(np.array([0.4])) == (0.4, 0.4, 0.4)
    assert confidence_interval(np.array([0.4, np.nan])) == (0.4, 0.4, 0.4)
    assert all(math.isnan(v) for v in confidence_interval(np.array([np.nan])))


def test_seed_statistics_groups_by_everything_but_the_seed(seed_sweep):
    stats = seed_statistics(collect_sweep(seed_sweep))
    assert len(stats) == 2 * 2  # ds values x methods
    assert (stats["n_seeds"] == 3).all()
    cmal5 = stats[(stats["method"] == "cmal") & (stats["matching.ds"] == 5)].iloc[0]
    expected = confidence_interval(np.array([0.15, 0.25, 0.35]))
    assert (cmal5["mean"], cmal5["ci_low"], cmal5["ci_high"]) == pytest.approx(expected)
    sad = stats[stats["method"] == "sad"]
    assert (sad["ci_low"] == sad["ci_high"]).all()  # seed-independent method: no spread


def test_seed_statistics_keeps_groups_whose_override_is_missing_in_some_jobs(tmp_path):
    write_job(tmp_path, "0", ["seed=0"], {("r", "p", "m"): 0.2})
    write_job(tmp_path, "1", ["seed=1"], {("r", "p", "m"): 0.4})
    write_job(tmp_path, "2", ["seed=0", "matching.ds=5"], {("r", "p", "m"): 0.6})
    stats = seed_statistics(collect_sweep(tmp_path))
    assert sorted(stats["n_seeds"]) == [1, 2]


def test_seed_statistics_needs_a_seed_column_and_a_known_metric(tmp_path):
    write_job(tmp_path, "0", ["matching.ds=5"], {("r", "p", "m"): 0.2})
    table = collect_sweep(tmp_path)
    with pytest.raises(ValueError, match="seed"):
        seed_statistics(table)
    with pytest.raises(ValueError, match="metric"):
        seed_statistics(table.assign(seed=0), metric="accuracy")


def test_seed_table_has_methods_as_rows_and_mean_ci_cells(seed_sweep):
    stats = seed_statistics(collect_sweep(seed_sweep))
    table = seed_table(stats[stats["matching.ds"] == 5])
    assert list(table.index) == ["cmal", "sad"]
    assert list(table.columns) == ["r1 a-b"]          # flat headers, no Python tuples
    assert table.loc["sad", "r1 a-b"] == "50.0% [50.0, 50.0]"
    row = stats[(stats["method"] == "cmal") & (stats["matching.ds"] == 5)].iloc[0]
    assert table.loc["cmal", "r1 a-b"] == format_mean_ci(row)
    assert format_mean_ci(row).startswith("25.0% [")
    assert "(" not in table.to_markdown()


def test_a_proportions_interval_is_shown_inside_0_to_100_percent():
    row = pd.Series({"mean": 0.819, "ci_low": 0.514, "ci_high": 1.124})
    assert format_mean_ci(row) == "81.9% [51.4, 100.0]"
    assert format_mean_ci(pd.Series({"mean": 0.02, "ci_low": -0.06, "ci_high": 0.10})) == \
        "2.0% [0.0, 10.0]"


def test_figure_stem_is_a_safe_file_name():
    assert figure_stem("matching.ds") == "matching-ds"
    assert figure_stem("models.cmal.iterations") == "models-cmal-iterations"


def test_aggregate_writes_the_table_figures_and_seed_table(seed_sweep, tmp_path):
    out = aggregate_sweep(seed_sweep, tmp_path / "reports" / "sweeps" / "demo")
    table = pd.read_csv(out / "results.csv")
    assert len(table) == 12 and "matching.ds" in table.columns
    for ext in ("png", "pdf"):
        assert (out / f"recall_at_100p_vs_matching-ds.{ext}").stat().st_size > 0
    assert not list(out.glob("recall_at_100p_vs_seed.*"))
    stats = pd.read_csv(out / "table2_seeds.csv")
    assert set(stats.columns) >= {"method", "n_seeds", "mean", "ci_low", "ci_high"}
    text = (out / "table2_seeds.md").read_text()
    assert "95% confidence interval" in text and "Student" in text


def test_aggregate_plots_against_training_iterations(tmp_path):
    for i, iterations in enumerate((100, 200, 400)):
        write_job(tmp_path / "sweep", str(i), [f"models.cmal.iterations={iterations}"],
                  {("r", "p", "cmal"): iterations / 1000})
    out = aggregate_sweep(tmp_path / "sweep", tmp_path / "out")
    assert (out / "recall_at_100p_vs_models-cmal-iterations.png").stat().st_size > 0
    assert not (out / "table2_seeds.csv").exists()


def objective_sweep(root, objective, cmal_values, *, val):
    """3 seeds: cmal = cmal_values[seed], control 0.2, sad 0.5; validation R@100P = val[seed]."""
    sweep = root / objective
    for seed in range(3):
        job = write_job(sweep, str(seed), [f"seed={seed}", f"objective={objective}"],
                        {("r1", "a-b", "cmal"): cmal_values[seed],
                         ("r1", "a-b", "cmal_untrained"): 0.2, ("r1", "a-b", "sad"): 0.5})
        label = "centre(reference)+L2, no enhancement"
        (job / "data" / "protocol").mkdir(parents=True)
        (job / "data" / "protocol" / "cmal.json").write_text(json.dumps({
            "selected": {"label": label},
            "candidates": [{"label": label, "mean_recall_at_100p": val[seed],
                            "mean_auc_pr": 0.9}, {"label": "raw", "mean_recall_at_100p": 1.0,
                                                  "mean_auc_pr": 1.0}]}))
    return sweep


def test_paired_difference_tests_over_seeds_and_flags_intervals_excluding_zero(tmp_path):
    from cmal_lcd.reports.seed_statistics import paired_difference

    table = collect_sweep(objective_sweep(tmp_path, "paper", [0.40, 0.42, 0.44], val=[0.5] * 3))
    diff = paired_difference(table, method="cmal", other="cmal_untrained")
    row = diff.iloc[0]
    assert row["mean"] == pytest.approx(0.22)
    assert row["significant"]
    assert row["ci_low"] == pytest.approx(0.22 - T_975[2] * 0.02 / math.sqrt(3))
    diff = paired_difference(table, method="cmal", other="sad")
    assert diff.iloc[0]["mean"] < 0 and diff.iloc[0]["significant"]


def test_seeds_report_uses_the_selected_protocols_validation_scores_only(tmp_path):
    from cmal_lcd.reports.seeds_report import write_seeds_report
    from cmal_lcd.reports.sweep_jobs import collect_validation

    a = objective_sweep(tmp_path, "paper", [0.4, 0.4, 0.4], val=[0.30, 0.32, 0.34])
    b = objective_sweep(tmp_path, "prior", [0.9, 0.9, 0.9], val=[0.20, 0.22, 0.24])
    validation = collect_validation(a, method="cmal")
    assert list(validation["val_recall_at_100p"]) == [0.30, 0.32, 0.34]  # never the 1.0 row
    readme = write_seeds_report({"paper": a, "prior": b}, tmp_path / "out", default="paper")
    text = readme.read_text()
    # the winner is chosen on validation (paper) although prior scores higher on the test route
    assert "Validation winner (mean R@100P): **paper**" in text
    assert "paper − prior: +10.0 points" in text and "not significant" not in text
    assert (tmp_path / "out" / "table2_prior.csv").is_file()


def test_each_heading_of_the_test_route_section_comes_right_before_its_own_lines(tmp_path):
    """"Targets" heads the target bullets and "Paired differences" the differences (the two
    headings once stood together above the targets)."""
    from cmal_lcd.reports.seeds_report import write_seeds_report

    a = objective_sweep(tmp_path, "paper", [0.4, 0.5, 0.6], val=[0.30, 0.32, 0.34])
    lines = write_seeds_report({"paper": a}, tmp_path / "out", default="paper").read_text() \
        .splitlines()
    targets = lines.index("Targets (seed means):")
    paired = lines.index("Paired differences (positive = the first method higher):")
    bullets = [i for i, line in enumerate(lines) if line.startswith("- ")]
    target_bullets = [i for i in bullets if lines[i].endswith(("**met**.", "**not met**."))]
    difference_bullets = [i for i in bullets if lines[i].startswith("- **")]
    assert target_bullets and difference_bullets
    assert targets < min(target_bullets) and max(target_bullets) < paired
    assert paired < min(difference_bullets)


def test_targets_count_pairs_on_seed_means_and_say_met_or_not():
    from cmal_lcd.reports.seeds_report import target_lines

    rows = []
    for seed in (0, 1):
        for k, pair in enumerate(["a", "b", "c", "d", "e", "f"]):
            # cmal beats the control on 5 pairs (not on f), ties SAD on a, beats it on b only
            values = {"cmal": 0.5 + 0.01 * seed, "cmal_untrained": 0.4 if pair != "f" else 0.6,
                      "sad": {"a": 0.5 + 0.01 * seed, "b": 0.3}.get(pair, 0.9), "bigan": 0.1}
            for method, value in values.items():
                rows.append({"route": "r", "pair": pair, "method": method, "seed": seed,
                             "recall_at_100p": value, "auc_pr": value})
    lines = target_lines(pd.DataFrame(rows))
    assert "5 of 6 pairs" in lines[0] and "**met**" in lines[0]
    assert "2 of 6 pairs" in lines[2] and "**not met**" in lines[2]
    assert "50.5% vs 10.0%" in lines[3] and "**met**" in lines[3]
    # one pair (Nordland): the same share of its pairs, said so
    one = target_lines(pd.DataFrame([r for r in rows if r["pair"] == "b"]))
    assert "1 of 1 pairs (target: at least 1 of 1; 5 of 6 on the rendered world): **met**" in (
        one[0])


def test_cmal_place_is_held_to_its_own_targets_not_cmals():
    from cmal_lcd.reports.seeds_report import target_lines

    rows = []
    for seed in (0, 1, 2):
        for pair in ["a", "b", "c", "d", "e", "f"]:
            # cmal_place reaches SAD on 3 pairs (a-c) and beats cmal by 10 +- 1 points a seed
            values = {"cmal_place": 0.6 + 0.01 * seed, "cmal": 0.5 + 0.02 * seed,
                      "sad": 0.55 if pair in "abc" else 0.9, "cmal_untrained": 0.1}
            for method, value in values.items():
                rows.append({"route": "r", "pair": pair, "method": method, "seed": seed,
                             "recall_at_100p": value, "auc_pr": value})
    lines = target_lines(pd.DataFrame(rows), focus="cmal_place")
    assert len(lines) == 2  # issue 36's two; not cmal's control or BiGAN targets
    assert "3 of 6 pairs (target: at least 4 of 6): **not met**" in lines[0]
    assert "significantly above cmal" in lines[1] and "+9.0 points" in lines[1]
    assert lines[1].endswith("**met**.")
    # a difference that changes sign across seeds is not significant
    flipped = pd.DataFrame(rows)
    flipped.loc[(flipped["method"] == "cmal") & (flipped["seed"] == 2), "recall_at_100p"] = 0.9
    assert target_lines(flipped, focus="cmal_place")[1].endswith("**not met**.")
    assert target_lines(flipped, focus="sad") == ["- sad: no issue sets a target for this method."]


def test_a_job_stopped_after_its_validation_step_counts_for_validation_only(tmp_path):
    from cmal_lcd.reports.seeds_report import write_seeds_report
    from cmal_lcd.reports.sweep_jobs import collect_validation

    a = objective_sweep(tmp_path, "paper", [0.4, 0.4, 0.4], val=[0.30, 0.32, 0.34])
    (a / "2" / "metrics.json").unlink()  # job 2 stopped after select_protocol
    validation = collect_validation(a, method="cmal")
    assert validation["finished"].tolist() == [True, True, False]
    assert len(validation) == 3
    readme = write_seeds_report({"paper": a}, tmp_path / "out", default="paper").read_text()
    assert "Stopped after the validation step" in readme and "paper seed 2" in readme


def test_the_objective_table_states_each_sweeps_training_iterations(tmp_path):
    """Objectives trained for different lengths must not be compared silently."""
    import yaml

    from cmal_lcd.reports.seeds_report import write_seeds_report
    from cmal_lcd.reports.sweep_jobs import collect_validation

    a = objective_sweep(tmp_path, "paper", [0.4] * 3, val=[0.30, 0.32, 0.34])
    b = objective_sweep(tmp_path, "prior", [0.4] * 3, val=[0.20, 0.22, 0.24])
    for sweep, iterations in ((a, 600), (b, 300)):
        for job in sweep.iterdir():
            (job / ".hydra" / "config.yaml").write_text(
                yaml.safe_dump({"models": {"cmal": {"iterations": iterations}}}))
    assert collect_validation(a, method="cmal")["iterations"].tolist() == [600] * 3
    text = write_seeds_report({"paper": a, "prior": b}, tmp_path / "out",
                              default="paper").read_text()
    assert "| paper | 3 | 600 |" in text and "| prior | 3 | 300 |" in text
    assert "mixes the objective with the training length" in text


def test_seeds_pool_over_jobs_that_differ_only_in_how_they_ran(tmp_path):
    """A seed reused from dvc repro (app.reuse) or run without BiGAN (methods) is the same
    experiment: its numbers join the other seeds' mean and interval."""
    from cmal_lcd.reports.seed_statistics import seed_statistics

    plumbing = [["app.reuse.models=/x/models", "app.steps=[evaluate]"],
                ["methods=[sad,cmal]"], []]
    for seed, extra in enumerate(plumbing):
        write_job(tmp_path / "sweep", f"seed{seed}", [f"seed={seed}", *extra],
                  {("r", "p", "cmal"): 0.2 + 0.1 * seed})
    stats_ = seed_statistics(collect_sweep(tmp_path / "sweep"))
    assert len(stats_) == 1
    row = stats_.iloc[0]
    assert row["n_seeds"] == 3 and row["mean"] == pytest.approx(0.3)
    assert row["ci_low"] < 0.2 < 0.4 < row["ci_high"]


def test_a_swept_setting_still_splits_the_seed_statistics(tmp_path):
    from cmal_lcd.reports.seed_statistics import seed_statistics

    for seed in range(2):
        for ds in (5, 10):
            write_job(tmp_path / "sweep", f"{seed}_{ds}", [f"seed={seed}", f"matching.ds={ds}"],
                      {("r", "p", "cmal"): ds / 100})
    stats_ = seed_statistics(collect_sweep(tmp_path / "sweep"))
    assert sorted(stats_["matching.ds"]) == [5, 10] and set(stats_["n_seeds"]) == {2}


def test_a_sweep_stopped_after_validation_gives_validation_rows_and_no_test_table(tmp_path):
    from cmal_lcd.reports.seeds_report import write_seeds_report

    a = objective_sweep(tmp_path, "paper", [0.4] * 3, val=[0.30, 0.32, 0.34])
    b = objective_sweep(tmp_path, "prior", [0.9] * 3, val=[0.20, 0.22, 0.24])
    for k, job in enumerate(sorted(a.iterdir())):  # killed, or stopped at select_protocol
        if k == 0:
            (job / "metrics.json").unlink()
        else:
            (job / "metrics.json").write_text("{}")
    text = write_seeds_report({"paper": a, "prior": b}, tmp_path / "out",
                              default="paper").read_text()
    assert "| paper | 3 |" in text and "Validation winner (mean R@100P): **paper**" in text
    assert "Validation only (no job of these sweeps evaluated the test routes): `paper`" in text
    assert "objective `paper`: Table II" not in text and "objective `prior`: Table II" in text
    assert not (tmp_path / "out" / "table2_paper.csv").exists()


def test_the_seeds_report_names_the_iteration_each_job_kept_from_its_own_or_reused_models(
        tmp_path):
    """A job that trained has models/<name>/selection.json; a job that reused another run's
    models (app.reuse.models, relative to the launch folder) is read from there."""
    from cmal_lcd.reports.seeds_report import write_seeds_report
    from cmal_lcd.reports.sweep_jobs import collect_validation

    sweep = objective_sweep(tmp_path, "prior", [0.6, 0.6, 0.6], val=[0.3, 0.3, 0.3])
    for seed, iteration in ((1, 200), (2, 100)):
        (sweep / str(seed) / "models" / "cmal").mkdir(parents=True)
        (sweep / str(seed) / "models" / "cmal" / "selection.json").write_text(
            json.dumps({"iteration": iteration, "select": "best_validation"}))
    launch = tmp_path / "checkout"
    (launch / "models" / "cmal").mkdir(parents=True)
    (launch / "models" / "cmal" / "selection.json").write_text(json.dumps({"iteration": 300}))
    job0 = sweep / "0" / ".hydra"
    (job0 / "config.yaml").write_text(yaml.safe_dump({"app": {"reuse": {"models": "models"}}}))
    (job0 / "hydra.yaml").write_text(yaml.safe_dump({"hydra": {"runtime": {"cwd": str(launch)}}}))
    assert list(collect_validation(sweep, method="cmal")["kept_iteration"]) == [300, 200, 100]
    text = write_seeds_report({"prior": sweep}, tmp_path / "out", default="prior").read_text()
    assert "| seed 0: 300, seed 1: 200, seed 2: 100 |" in text


def test_the_seeds_report_names_the_processor_that_trained_each_jobs_model(tmp_path):
    """Weights differ across processor families: the report says which processor trained the
    jobs' CMAL (``kernels.cpu`` in ``model.pt``), counting jobs per processor."""
    import torch

    from cmal_lcd.reports.seeds_report import write_seeds_report
    from cmal_lcd.reports.sweep_jobs import training_processor

    sweep = objective_sweep(tmp_path, "prior", [0.6, 0.6, 0.6], val=[0.3, 0.3, 0.3])
    for seed, cpu in ((0, "CPU A"), (1, "CPU A"), (2, None)):
        (sweep / str(seed) / "models" / "cmal").mkdir(parents=True)
        record = {"iteration": 5, **({"kernels": {"cpu": cpu}} if cpu else {})}
        torch.save(record, sweep / str(seed) / "models" / "cmal" / "model.pt")
    assert training_processor(sweep / "0", "cmal") == "CPU A"
    assert training_processor(sweep / "2", "cmal") is None
    text = write_seeds_report({"prior": sweep}, tmp_path / "out", default="prior").read_text()
    assert "Trained on: CPU A (2 jobs); not recorded (1 job)." in text


def test_the_seeds_report_carries_its_jobs_records_and_reads_them_again(tmp_path):
    """No reference to a folder the reader lacks: each job's overrides, config, metrics and
    protocols are copied under jobs/<sweep>/, the README names them there and no absolute
    path, and the report made from the copies has the same tables."""
    from cmal_lcd.reports.seeds_report import write_seeds_report

    a = objective_sweep(tmp_path / "far" / "away", "paper", [0.4, 0.5, 0.6],
                        val=[0.30, 0.32, 0.34])
    for job in a.iterdir():                     # run plumbing naming this machine's folders
        overrides = yaml.safe_load((job / ".hydra" / "overrides.yaml").read_text())
        (job / ".hydra" / "overrides.yaml").write_text(yaml.safe_dump(
            [*overrides, f"app.reuse.dataset={tmp_path}/data"]))
        (job / ".hydra" / "config.yaml").write_text(yaml.safe_dump(
            {"seed": 0, "app": {"reuse": {"dataset": f"{tmp_path}/data"}}}))
    out = tmp_path / "out"
    text = write_seeds_report({"paper": a}, out, default="paper").read_text()
    assert "`jobs/paper/`" in text and str(tmp_path) not in text
    for job in ("0", "1", "2"):
        for name in (".hydra/overrides.yaml", "metrics.json", "data/protocol/cmal.json"):
            assert (out / "jobs" / "paper" / job / name).is_file(), (job, name)
    for name in ("validation.csv", "invariance.csv", "table2_paper.csv", "README.md"):
        assert str(tmp_path) not in (out / name).read_text(), name
    for job in (out / "jobs" / "paper").iterdir():   # how the job ran is not carried
        for name in (".hydra/overrides.yaml", ".hydra/config.yaml"):
            record = (job / name).read_text() if (job / name).is_file() else ""
            assert "app." not in record and "app:" not in record and str(tmp_path) not in record
    again = write_seeds_report({"paper": out / "jobs" / "paper"}, tmp_path / "again",
                               default="paper")
    assert (tmp_path / "again" / "table2_paper.csv").read_text() == \
        (out / "table2_paper.csv").read_text()
    assert again.read_text().split("## ", 1)[1] == text.split("## ", 1)[1]


def test_a_seeds_report_rebuilt_from_its_copies_keeps_row_labels_and_processor(tmp_path):
    """The copies carry what the header needs without the weights: each method's row label
    (data/features/<method>/info.json) and the processor that trained each model."""
    import torch

    from cmal_lcd.reports.seeds_report import write_seeds_report

    sweep = objective_sweep(tmp_path, "place", [0.6, 0.6, 0.6], val=[0.3, 0.3, 0.3])
    for job in sweep.iterdir():
        (job / "models" / "cmal").mkdir(parents=True)
        torch.save({"kernels": {"cpu": "CPU A"}}, job / "models" / "cmal" / "model.pt")
        (job / "data" / "features" / "cmal").mkdir(parents=True)
        (job / "data" / "features" / "cmal" / "info.json").write_text(
            json.dumps({"label": "CMAL (paper objective, eqs. 9-12)"}))
    text = write_seeds_report({"place": sweep}, tmp_path / "out", default="place").read_text()
    assert "- `cmal`: CMAL (paper objective, eqs. 9-12)" in text
    assert "Trained on: CPU A (3 jobs)." in text
    for round_ in ("again", "twice"):             # a copy of a copy loses nothing either
        source = tmp_path / ("out" if round_ == "again" else "again") / "jobs" / "place"
        rebuilt = write_seeds_report({"place": source}, tmp_path / round_,
                                     default="place").read_text()
        assert rebuilt.splitlines()[3:] == text.splitlines()[3:]
        assert not list((tmp_path / round_).rglob("model.pt"))


def test_a_jobs_setting_is_read_with_its_interpolations_resolved(tmp_path):
    from cmal_lcd.reports.sweep_jobs import job_setting

    (tmp_path / ".hydra").mkdir()
    (tmp_path / ".hydra" / "config.yaml").write_text(
        "models:\n  cmal: {iterations: 250}\n  cmal_place: {iterations: '${models.cmal.iterations}'}\n")
    assert job_setting(tmp_path, "models.cmal_place.iterations") == 250
    assert job_setting(tmp_path, "models.cmal") == {"iterations": 250}
    assert job_setting(tmp_path, "models.bigan.iterations") is None


def test_a_paired_differences_interval_stays_inside_plus_minus_100_points():
    from cmal_lcd.reports.seeds_report import _difference_lines

    diff = pd.DataFrame([{"route": "r1", "pair": "a-b", "n_seeds": 3, "mean": 0.533,
                          "ci_low": 0.055, "ci_high": 1.010, "significant": True}])
    line = _difference_lines(diff, method="x", other="y")[0]
    assert "+53.3 [+5.5, +100.0]" in line and "101" not in line


def test_the_seeds_report_says_what_each_row_is_and_compares_nothing_with_one_sweep(tmp_path):
    from cmal_lcd.reports.seeds_report import write_seeds_report

    a = objective_sweep(tmp_path, "place", [0.4, 0.5, 0.6], val=[0.30, 0.32, 0.34])
    (a / "0" / "data" / "features" / "cmal").mkdir(parents=True)
    (a / "0" / "data" / "features" / "cmal" / "info.json").write_text(
        json.dumps({"label": "CMAL (+ eq. 7 prior) + place (extension)"}))
    text = write_seeds_report({"place": a}, tmp_path / "out", default="place").read_text()
    assert "- `cmal`: CMAL (+ eq. 7 prior) + place (extension)" in text
    assert "Validation winner" not in text


def test_the_strict_variant_tables_read_each_methods_evaluation_files(tmp_path):
    from cmal_lcd.reports.seeds_report import write_seeds_report

    sweep = objective_sweep(tmp_path, "nordland", [0.9, 0.9, 0.9], val=[0.5] * 3)
    for seed, job in enumerate(sorted(p for p in sweep.iterdir())):
        (job / ".hydra" / "config.yaml").write_text(yaml.safe_dump(
            {"matching": {"d_thresh": 20, "d_thresh_strict": 2}}))
        for method, strict in (("cmal", 0.3 + 0.1 * seed), ("sad", 0.1)):
            folder = job / "data" / "evaluation" / method
            folder.mkdir(parents=True)
            metrics = {m: 0.9 for m in METRICS}
            (folder / "metrics.json").write_text(json.dumps({"r1": {"a-b": {
                "selected": metrics, "paper": metrics,
                "strict": {**{m: strict for m in METRICS}, "d_thresh": 2}}}}))
    strict = collect_sweep(sweep, variant="strict")
    cmal = strict[strict["method"] == "cmal"].sort_values("seed")
    assert list(cmal["recall_at_100p"]) == pytest.approx([0.3, 0.4, 0.5])
    assert set(strict["method"]) == {"cmal", "sad"}  # only what the files hold
    assert set(collect_sweep(sweep)["method"]) == {"cmal", "cmal_untrained", "sad"}
    text = write_seeds_report({"nordland": sweep}, tmp_path / "out", default="nordland",
                              variant="strict").read_text()
    assert "strict tolerance" in text and "±2 frame(s)" in text and "±20 frames" in text
    assert "40.0%" in text  # the strict mean, not the main tolerance's 90%
    with pytest.raises(ValueError, match="variant 'nope'"):
        collect_sweep(sweep, variant="nope")


def test_a_seeds_report_replaces_its_folder_as_a_whole_and_refuses_a_foreign_one(tmp_path):
    """Issue 38 ("one writer"): seeds-report wrote file by file, so an earlier report's
    ``table2_<objective>.csv`` stayed beside a new report that has no such objective, and a
    failure half-way left a mix. It now writes as ``match`` and ``loops`` do."""
    from cmal_lcd.reports.seeds_report import write_seeds_report

    a = objective_sweep(tmp_path, "paper", [0.4, 0.4, 0.4], val=[0.30, 0.32, 0.34])
    b = objective_sweep(tmp_path, "prior", [0.9, 0.9, 0.9], val=[0.20, 0.22, 0.24])
    out = tmp_path / "out"
    write_seeds_report({"paper": a, "prior": b}, out, default="paper")
    assert (out / "table2_prior.csv").is_file() and (out / "jobs" / "prior").is_dir()
    write_seeds_report({"paper": a}, out, default="paper")
    assert sorted(p.name for p in out.iterdir()) == [
        "README.md", "invariance.csv", "jobs", "table2_paper.csv", "validation.csv"]
    assert [p.name for p in (out / "jobs").iterdir()] == ["paper"]
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    (out / "notes.txt").write_text("mine")
    with pytest.raises(ValueError, match=rf"^{out}: --out holds an entry seeds-report did not "
                                         r"write \(first 'notes.txt'\)"):
        write_seeds_report({"paper": a, "prior": b}, out, default="paper")
    (out / "notes.txt").unlink()
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out", "paper", "prior"]


def test_aggregate_replaces_its_folder_as_a_whole_and_refuses_a_foreign_one(seed_sweep,
                                                                           tmp_path):
    out = tmp_path / "demo"
    aggregate_sweep(seed_sweep, out)
    (out / "recall_at_100p_vs_old-key.png").write_bytes(b"an earlier sweep's figure")
    aggregate_sweep(seed_sweep, out)
    assert not (out / "recall_at_100p_vs_old-key.png").exists()
    (out / "README.md").write_text("mine")
    with pytest.raises(ValueError, match="--out holds an entry aggregate did not write "
                                         r"\(first 'README.md'\)"):
        aggregate_sweep(seed_sweep, out)
    assert (out / "README.md").read_text() == "mine"


def test_a_row_labelled_differently_by_two_sweeps_says_which_label_is_whose(tmp_path):
    """Issue 36 item 2: the seeds report over the paper and the default objective called its
    `cmal` row "CMAL (paper objective, eqs. 9-12)" for both sweeps."""
    from cmal_lcd.reports.seeds_report import write_seeds_report

    sweeps = {}
    for objective, label in (("paper", "CMAL (paper objective, eqs. 9-12)"),
                             ("prior_adversary", "CMAL (+ eq. 7 prior, eq. 8 adversary)")):
        sweeps[objective] = objective_sweep(tmp_path, objective, [0.4] * 3, val=[0.3] * 3)
        for job in sweeps[objective].iterdir():
            for method, text in (("cmal", label), ("sad", "SAD")):
                (job / "data" / "features" / method).mkdir(parents=True)
                (job / "data" / "features" / method / "info.json").write_text(
                    json.dumps({"label": text}))
    text = write_seeds_report(sweeps, tmp_path / "out", default="paper").read_text()
    assert ("- `cmal`: CMAL (paper objective, eqs. 9-12) (sweep `paper`); CMAL (+ eq. 7 prior, "
            "eq. 8 adversary) (sweep `prior_adversary`)") in text
    assert "- `sad`: SAD\n" in text
