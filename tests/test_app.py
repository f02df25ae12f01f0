"""``cmal-lcd-run``: the whole chain on one config, single runs and ``-m`` sweeps.

Every command of docs/sweeps.md that runs the app is exercised here at tiny size
(``debug=tiny``), launched from a scratch git repository with the project's ``.gitignore``:

- one full chain (module fixture; every step of ``app.steps``, ``calibrate_world`` included),
  whose dataset, models and features the sweeps then reuse (``app.reuse.*``), so that no sweep
  job retrains unless it sweeps training;
- ``-m`` with the basic launcher, ``hydra/launcher=joblib`` and ``hydra/launcher=submitit_local``;
- the ``seeds`` experiment (trains CMAL and BiGAN per seed) and ``cmal-lcd aggregate``.

The DNN method is left out of the sweeps (``methods=[...]``): it costs most of a tiny run's time
and does not depend on any swept parameter.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

from cmal_lcd.app import flat_summary, models_to_train, objective, run_chain
from subprocess_helpers import run_checked

from cmal_lcd.config import REPO_ROOT, compose

METRICS = ("auc_pr", "auc_roc", "recall_at_100p", "recall_at_1", "single_frame_recall_at_1")
PAIRS = {"foggy-rainy", "foggy-sunny", "rainy-sunny"}
ROUTES = {"route1", "route2"}
METHODS = ["sad", "bigan", "cmal", "cmal_untrained"]
APP = [sys.executable, "-m", "cmal_lcd.app"]
CLI = [sys.executable, "-m", "cmal_lcd.commands"]


def run(cmd: list[str], cwd: Path, timeout: float = 600) -> subprocess.CompletedProcess:
    return run_checked(cmd, cwd, timeout=timeout)


def untracked_outside_hydra_folders(repo: Path) -> list[str]:
    """``git status --porcelain`` lines (ignored files excluded: outputs/, multirun/)."""
    out = run(["git", "status", "--porcelain", "--untracked-files=all"], repo).stdout
    return [line for line in out.splitlines() if line.strip()]


def job_dirs(sweep: Path) -> list[Path]:
    return sorted((p for p in sweep.iterdir() if (p / ".hydra").is_dir()),
                  key=lambda p: int(p.name))


def summary(job: Path) -> dict:
    return json.loads((job / "metrics.json").read_text())


def reuse_overrides(run_dir: Path) -> list[str]:
    return [f"app.reuse.dataset={run_dir / 'data' / 'dataset'}",
            f"app.reuse.models={run_dir / 'models'}",
            f"app.reuse.features={run_dir / 'data' / 'features'}"]


@pytest.fixture(scope="module")
def launch_dir(tmp_path_factory) -> Path:
    """A scratch git repository with the project's .gitignore, conf/ and a committed file
    (``cmal-lcd-run`` composes the conf/ of the checkout it runs in)."""
    repo = tmp_path_factory.mktemp("launch")
    shutil.copy2(REPO_ROOT / ".gitignore", repo / ".gitignore")
    shutil.copytree(REPO_ROOT / "conf", repo / "conf")
    (repo / "README.md").write_text("scratch\n")
    run(["git", "init", "-q"], repo)
    run(["git", "add", "-A"], repo)
    run(["git", "-c", "user.email=t@t", "-c", "user.name=t", "commit", "-qm", "scratch"], repo)
    return repo


@pytest.fixture(scope="module")
def tiny_run(launch_dir) -> Path:
    """``cmal-lcd-run debug=tiny methods=[...]``: the job folder of one whole chain."""
    run(APP + ["debug=tiny", f"methods=[{','.join(METHODS)}]"], launch_dir)
    runs = sorted((launch_dir / "outputs").glob("*/*/metrics.json"))
    assert len(runs) == 1, runs
    return runs[0].parent


# ------------------------------------------------------------------------------ pure helpers


def test_models_to_train_follows_the_methods():
    """The models the methods read, in ``model_names``' order (tests/test_chain.py: the same
    models as dvc.yaml's ``train`` matrix for every shipped config)."""
    assert models_to_train(["sad", "cmal"], ["cmal", "bigan"]) == ["cmal"]
    assert models_to_train(["sad", "bigan"], ["cmal", "bigan"]) == ["bigan"]
    # the untrained control is encoded under the trained CMAL classifier's decision
    assert models_to_train(["sad", "cmal_untrained"], ["cmal", "bigan"]) == ["cmal"]
    assert models_to_train(["sad", "dnn", "dnn_head"], ["cmal", "bigan"]) == []
    assert models_to_train(["bigan", "cmal"], ["cmal", "bigan"]) == ["cmal", "bigan"]


def test_flat_summary_keeps_the_paper_variant():
    evaluations = {"sad": {"r": {"a-b": {"selected": {"auc_pr": 0.5}, "paper": {"auc_pr": 0.9}}}}}
    assert flat_summary(evaluations) == {"r/a-b/sad/auc_pr": 0.5}
    assert flat_summary(evaluations, variant="paper") == {"r/a-b/sad/auc_pr": 0.9}
    with pytest.raises(ValueError, match="variant"):
        flat_summary(evaluations, variant="other")


def test_objective_averages_learned_methods_only():
    flat = {"r/p/sad/recall_at_100p": 1.0, "r/p/cmal/recall_at_100p": 0.2,
            "r/q/bigan/recall_at_100p": 0.4, "r/p/cmal/auc_pr": 0.9}
    assert objective(flat) == pytest.approx(0.3)
    assert objective({"r/p/sad/recall_at_100p": 1.0}) is None


# ------------------------------------------------------------------------------- single run


def test_single_run_writes_the_chain_into_its_job_folder(tiny_run):
    for path in ("data/dataset/images.npy", "data/manifest.csv", "reports/world/difficulty.json",
                 "models/cmal/model.pt", "models/bigan/model.pt",
                 "data/features/cmal/codes.npy", "data/evaluation/cmal/metrics.json",
                 "data/evaluation/invariance.json", "reports/README.md",
                 "reports/metrics.json", ".hydra/config.yaml", ".hydra/overrides.yaml"):
        assert (tiny_run / path).is_file(), path
    # calibrate_world measured the rendered world (a folder dataset would record a skip)
    assert "routes" in json.loads((tiny_run / "reports/world/difficulty.json").read_text())
    # evaluate_loops: every route's looping traversals, in the report
    for method in METHODS:
        loops = json.loads((tiny_run / f"data/evaluation_loops/{method}/metrics.json").read_text())
        assert {r: sorted(v) for r, v in loops.items()} == {
            r: ["sunny-foggy", "sunny-rainy", "sunny-sunny"] for r in ROUTES}
    assert "Loop closure within one drive" in (tiny_run / "reports/README.md").read_text()
    flat = summary(tiny_run)
    expected = {f"{r}/{p}/{m}/{k}" for r in ROUTES for p in PAIRS for m in METHODS
                for k in METRICS}
    assert expected <= set(flat)
    for key in expected:
        assert 0.0 <= flat[key] <= 1.0, key


def test_job_summary_is_the_report_metrics_flattened(tiny_run):
    report = json.loads((tiny_run / "reports" / "metrics.json").read_text())
    flat = summary(tiny_run)
    for route, pairs in report.items():
        for pair, methods in pairs.items():
            for method, values in methods.items():
                for key, value in values.items():
                    assert flat[f"{route}/{pair}/{method}/{key}"] == value


def test_app_writes_nothing_into_tracked_paths(launch_dir, tiny_run):
    assert untracked_outside_hydra_folders(launch_dir) == []
    top = {p.name for p in launch_dir.iterdir()}
    assert top <= {".git", ".gitignore", "README.md", "conf", "outputs", "multirun", "reports"}, top


def test_unknown_step_is_an_error_naming_app_steps(tmp_path):
    cfg = compose(["debug=tiny", "app.steps=[evaluate,bogus]"], config_name="app")
    with pytest.raises(ValueError, match=r"app\.steps.*bogus"):
        run_chain(cfg, tmp_path)


def test_missing_reused_folder_is_an_error_naming_the_key(tmp_path):
    cfg = compose(["debug=tiny", f"app.reuse.dataset={tmp_path / 'nothing'}"],
                  config_name="app")
    with pytest.raises(FileNotFoundError, match=r"app\.reuse\.dataset"):
        run_chain(cfg, tmp_path)
    assert not (tmp_path / "metrics.json").exists()


# ------------------------------------------------------------------------------ sweeps


@pytest.fixture(scope="module")
def ds_sweep(launch_dir, tiny_run) -> Path:
    """Basic launcher: a SeqSLAM-only sweep reusing the single run's dataset/models/features."""
    sweep = launch_dir / "multirun" / "ds"
    run(APP + ["-m", "debug=tiny", "methods=[sad,cmal]", "matching.ds=5,8",
               "app.steps=[select_protocol,evaluate]",
               *reuse_overrides(tiny_run), f"hydra.sweep.dir={sweep}"], launch_dir)
    return sweep


def test_basic_sweep_runs_one_job_per_value_without_retraining(ds_sweep, tiny_run):
    jobs = job_dirs(ds_sweep)
    assert [j.name for j in jobs] == ["0", "1"]
    for job, ds in zip(jobs, (5, 8)):
        overrides = (job / ".hydra" / "overrides.yaml").read_text()
        assert f"matching.ds={ds}" in overrides
        # the reused folders are links into the job (read on dvc.yaml's paths), not copies
        assert (job / "models").is_symlink() and (job / "data" / "dataset").is_symlink()
        assert not (job / "checkpoints").exists()
        flat = summary(job)
        assert {k.split("/")[2] for k in flat} == {"sad", "cmal"}
        # the look-back length changes how many queries are scored
        n_query = flat["route1/foggy-rainy/sad/n_query"]
        assert flat["route1/foggy-rainy/sad/n_scored"] <= n_query - ds
    n5 = summary(jobs[0])["route1/foggy-rainy/cmal/n_scored"]
    n8 = summary(jobs[1])["route1/foggy-rainy/cmal/n_scored"]
    assert n5 > n8


def test_a_job_with_the_same_params_reproduces_the_single_run(tiny_run, tmp_path):
    """Same params (ds=10, the default) on the reused folders: identical numbers."""
    cfg = compose(["debug=tiny", "methods=[sad,cmal]", "app.steps=[select_protocol,evaluate]",
                   *reuse_overrides(tiny_run)], config_name="app")
    again, first = run_chain(cfg, tmp_path), summary(tiny_run)
    assert again == summary(tmp_path)
    assert {k.split("/")[2] for k in again} == {"sad", "cmal"}
    assert all(first[k] == v for k, v in again.items())


def test_joblib_launcher_runs_two_jobs_in_parallel_processes(launch_dir, tiny_run):
    sweep = launch_dir / "multirun" / "joblib"
    result = run(APP + ["-m", "hydra/launcher=joblib", "hydra.launcher.n_jobs=2", "debug=tiny",
                        "methods=[sad]", "matching.r_window=5,10",
                        "app.steps=[select_protocol,evaluate]",
                        *reuse_overrides(tiny_run), f"hydra.sweep.dir={sweep}"], launch_dir)
    assert "Joblib" in result.stdout + result.stderr
    jobs = job_dirs(sweep)
    assert len(jobs) == 2 and all(summary(j) for j in jobs)


def test_submitit_local_launcher_runs_the_jobs(launch_dir, tiny_run):
    sweep = launch_dir / "multirun" / "submitit"
    run(APP + ["-m", "hydra/launcher=submitit_local", "hydra.launcher.timeout_min=10",
               "hydra.launcher.cpus_per_task=1", "hydra.launcher.tasks_per_node=1",
               "debug=tiny", "methods=[sad]", "matching.v_max=1.1,1.2",
               "app.steps=[select_protocol,evaluate]",
               *reuse_overrides(tiny_run), f"hydra.sweep.dir={sweep}"], launch_dir)
    jobs = job_dirs(sweep)
    assert len(jobs) == 2 and all(summary(j) for j in jobs)
    assert (sweep / ".submitit").is_dir()


def test_aggregate_turns_a_sweep_into_a_table_and_figures(launch_dir, ds_sweep):
    run(CLI + ["aggregate", str(ds_sweep), "--name", "ds"], launch_dir)
    out = launch_dir / "reports" / "sweeps" / "ds"
    table = pd.read_csv(out / "results.csv")
    assert sorted(table["matching.ds"].unique()) == [5, 8]
    assert set(table["method"]) == {"sad", "cmal"}
    assert len(table) == 2 * 2 * len(ROUTES) * len(PAIRS)  # jobs x methods x routes x pairs
    for ext in ("png", "pdf"):
        assert (out / f"recall_at_100p_vs_matching-ds.{ext}").stat().st_size > 0


def test_seeds_experiment_trains_both_models_per_seed_and_writes_table2(launch_dir, tiny_run):
    sweep = launch_dir / "multirun" / "seeds"
    run(APP + ["-m", "experiment=seeds", "debug=tiny", "seed=0,1",
               f"app.reuse.dataset={tiny_run / 'data' / 'dataset'}",
               "app.steps=[train,extract_features,select_protocol,evaluate]",
               f"hydra.sweep.dir={sweep}"],
        launch_dir)
    jobs = job_dirs(sweep)
    assert len(jobs) == 2
    for job in jobs:
        assert (job / "models" / "cmal" / "model.pt").is_file()
        assert (job / "models" / "bigan" / "model.pt").is_file()
        assert {k.split("/")[2] for k in summary(job)} == {"sad", "bigan", "cmal",
                                                            "cmal_untrained"}
    run(CLI + ["aggregate", str(sweep), "--name", "seeds"], launch_dir)
    out = launch_dir / "reports" / "sweeps" / "seeds"
    stats = pd.read_csv(out / "table2_seeds.csv")
    assert set(stats["method"]) == {"sad", "bigan", "cmal", "cmal_untrained"}
    assert (stats["n_seeds"] == 2).all()
    assert ((stats["ci_low"] <= stats["mean"]) & (stats["mean"] <= stats["ci_high"])).all()
    # SAD does not depend on the training seed: its two values agree, the interval is a point
    sad = stats[stats["method"] == "sad"]
    assert (sad["ci_low"] == sad["ci_high"]).all()
    text = (out / "table2_seeds.md").read_text()
    assert "Student" in text and "cmal" in text


# ------------------------------------------------------------------------ launcher presets


def compose_with_hydra(overrides: list[str]):
    from hydra import compose as hydra_compose
    from hydra import initialize_config_dir

    from cmal_lcd.config import CONF_DIR

    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        return hydra_compose(config_name="app", overrides=overrides, return_hydra_config=True)


def test_slurm_preset_is_the_submitit_slurm_launcher_with_cluster_keys():
    cfg = compose_with_hydra(["hydra/launcher=slurm", "hydra.launcher.partition=cpu",
                              "hydra.launcher.timeout_min=30"])
    launcher = cfg.hydra.launcher
    # the project's checked subclass of submitit's SLURM launcher (cmal_lcd.slurm)
    assert launcher._target_ == "hydra_plugins.cmal_lcd_slurm.launcher.SlurmLauncher"
    assert (launcher.partition, launcher.timeout_min, launcher.cpus_per_task) == ("cpu", 30, 4)
    assert launcher.submitit_folder.endswith(".submitit/%j")  # submitit_slurm's keys kept



@pytest.mark.parametrize("job", [".", "data/job", "reports"])
def test_a_job_inside_the_checkouts_tracked_paths_is_refused(job, monkeypatch, tmp_path):
    """Issue 38 item 7: ``cmal-lcd-run hydra.run.dir=.`` wrote ``data/dataset`` and
    ``data/manifest.csv`` (dvc repro's outputs) into the checkout root."""
    from cmal_lcd.app import chain_runs, check_outside_tracked_paths
    from cmal_lcd.config import REPO_ROOT

    monkeypatch.chdir(REPO_ROOT)
    runs = chain_runs(compose([]), REPO_ROOT / "dvc.yaml")
    with pytest.raises(ValueError, match="inside the checkout's DVC-tracked"):
        check_outside_tracked_paths(REPO_ROOT / job, runs, runs)
    check_outside_tracked_paths(REPO_ROOT / "outputs" / "job", runs, runs)  # the default
    # the runs of reused folders write nothing: a job making none may be anywhere
    check_outside_tracked_paths(REPO_ROOT / job, [], runs)


@pytest.mark.parametrize("overrides, named", [
    (["matching.dss=3"], "Could not override 'matching.dss'"),
    (["matching.ds=[1,"], "no viable alternative at input '[1,'"),
    (["debug=huge"], "Could not find 'debug/huge' Available options in 'debug': tiny"),
    (["-m", "seed=0,1", "matching.ds=0"], "matching.ds: must be >= 1, got 0"),
])
def test_a_bad_override_is_one_line_and_exit_2(overrides, named, tmp_path):
    """Issue 38 item 10: Hydra printed its own multi-line text and exited 1."""
    from cmal_lcd.config import REPO_ROOT

    done = subprocess.run([sys.executable, "-m", "cmal_lcd.app", *overrides,
                           f"hydra.run.dir={tmp_path / 'job'}",
                           f"hydra.sweep.dir={tmp_path / 'sweep'}"],
                          cwd=REPO_ROOT, capture_output=True, text=True, timeout=120)
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2 and len(lines) == 1, done.stderr
    assert lines[0].startswith("cmal-lcd-run: error: ") and named in lines[0], lines[0]
    assert not (tmp_path / "job").exists() and not (tmp_path / "sweep").exists()
