"""DVC experiments on the same ``conf/``: ``dvc exp run -S`` and queued sweeps.

A scratch copy of the repository (tracked and staged files, as a clone would have them) is made
tiny by selecting ``debug: tiny`` in its ``conf/config.yaml`` (with ``hydra.enabled`` DVC
recomposes ``params.yaml`` from ``conf/`` before every ``dvc exp run``, so a tiny
``params.yaml`` alone would be overwritten) and by comparing two methods only. The queued sweep
(``dvc exp run --queue`` + ``dvc queue start``, celery workers) is marked ``slow``.
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import time
from pathlib import Path

import pytest
import yaml

from subprocess_helpers import run_checked

from cmal_lcd.config import REPO_ROOT, compose_params_yaml

METHODS = ("sad", "cmal")


def run(cmd: list[str], cwd: Path, timeout: float = 900) -> subprocess.CompletedProcess:
    return run_checked(cmd, cwd, timeout=timeout)


def repo_files() -> list[str]:
    out = run(["git", "ls-files", "-co", "--exclude-standard"], REPO_ROOT).stdout.split("\n")
    return [f for f in out if f and (REPO_ROOT / f).is_file()
            and not f.startswith(("reports/", "outputs/", "multirun/"))
            and f != "dvc.lock"]


def make_tiny_config(conf: Path) -> None:
    """Select ``debug: tiny`` and two methods in a copy's ``conf/config.yaml``."""
    config = conf / "config.yaml"
    text = config.read_text()
    methods = re.search(r"\nmethods: .*\n", text)
    assert "  - debug: null\n" in text and methods, "conf/config.yaml changed its layout"
    text = text.replace("  - debug: null\n", "  - debug: tiny\n")
    text = text.replace(methods.group(0), f"\nmethods: [{', '.join(METHODS)}]\n")
    config.write_text(text)


def make_scratch_repo(dest: Path) -> Path:
    for name in repo_files():
        target = dest / name
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(REPO_ROOT / name, target)
    make_tiny_config(dest / "conf")
    compose_params_yaml(output=dest / "params.yaml", config_dir=dest / "conf")
    run(["git", "init", "-q"], dest)
    run(["dvc", "config", "hydra.enabled", "true"], dest)
    run(["git", "add", "-A"], dest)
    run(["git", "-c", "user.email=t@t", "-c", "user.name=t", "commit", "-qm", "tiny"], dest)
    return dest


def params(repo: Path) -> dict:
    return yaml.safe_load((repo / "params.yaml").read_text())


@pytest.fixture(scope="module")
def scratch(tmp_path_factory) -> Path:
    return make_scratch_repo(tmp_path_factory.mktemp("dvcexp"))


def test_scratch_config_is_tiny_and_composes_like_dvc(scratch):
    p = params(scratch)
    assert p["methods"] == list(METHODS)
    assert p["data"]["image_size"] == [32, 32]
    assert p["matching"]["ds"] == 10


@pytest.fixture(scope="module")
def exp_run(scratch) -> subprocess.CompletedProcess:
    """``dvc exp run -S matching.ds=8`` in the scratch repository."""
    return run(["dvc", "exp", "run", "-S", "matching.ds=8"], scratch)


def test_exp_run_with_set_param_recomposes_params_and_runs_the_pipeline(scratch, exp_run):
    assert params(scratch)["matching"]["ds"] == 8
    metrics = json.loads((scratch / "reports" / "metrics.json").read_text())
    for route, pairs in metrics.items():
        for pair, methods in pairs.items():
            assert set(methods) == set(METHODS)
    evaluation = json.loads((scratch / "data" / "evaluation" / "sad" / "metrics.json")
                            .read_text())
    for pairs in evaluation.values():
        for variants in pairs.values():
            values = variants["selected"]
            assert values["n_scored"] <= values["n_query"] - 8


def test_exp_show_lists_the_experiment_with_its_param(scratch, exp_run):
    shown = json.loads(run(["dvc", "exp", "show", "--json"], scratch).stdout)
    text = json.dumps(shown)
    assert '"ds": 8' in text
    assert "recall_at_100p" in text


def test_conf_remains_the_single_source(scratch, exp_run):
    """The experiment changed params.yaml only through the -S override, never conf/."""
    assert run(["git", "status", "--porcelain", "conf"], scratch).stdout.strip() == ""
    fresh = compose_params_yaml(["matching.ds=8"], output=scratch / "fresh.yaml",
                                config_dir=scratch / "conf")
    assert fresh.read_text() == (scratch / "params.yaml").read_text()
    fresh.unlink()


@pytest.mark.slow
def test_queued_sweep_runs_each_value_as_an_experiment(scratch, exp_run):
    # the queue runs experiments from HEAD: commit the baseline so the run cache is reused
    run(["git", "add", "-A"], scratch)
    run(["git", "-c", "user.email=t@t", "-c", "user.name=t", "commit", "-qm", "baseline"],
        scratch)
    run(["dvc", "exp", "run", "--queue", "-S", "matching.ds=6,12"], scratch)
    queued = run(["dvc", "queue", "status"], scratch).stdout
    assert queued.count("Queued") == 2, queued
    run(["dvc", "queue", "start", "-j", "1"], scratch)
    deadline = time.monotonic() + 900
    while time.monotonic() < deadline:
        status = run(["dvc", "queue", "status"], scratch).stdout
        if "Queued" not in status and "Running" not in status:
            break
        time.sleep(5)
    run(["dvc", "queue", "stop", "--kill"], scratch) if "Running" in status else None
    assert status.count("Success") == 2, status
    shown = json.dumps(json.loads(run(["dvc", "exp", "show", "--json"], scratch).stdout))
    assert '"ds": 6' in shown and '"ds": 12' in shown
