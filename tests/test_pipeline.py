"""`dvc repro` runs the whole chain and `reports/` holds every promised file.

Runs the real DVC pipeline on the tiny debug config in a temporary copy of the repository
(its tracked and staged files, as a fresh clone would have them), then checks the reports.
"""

import json
import math
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from cmal_lcd.config import REPO_ROOT, compose_params_yaml

METRICS = ("auc_pr", "auc_roc", "recall_at_100p", "recall_at_1", "single_frame_recall_at_1")


def repo_files() -> list[str]:
    out = subprocess.run(["git", "ls-files", "-co", "--exclude-standard"], cwd=REPO_ROOT,
                         check=True, capture_output=True, text=True).stdout.split("\n")
    return [f for f in out if f and (REPO_ROOT / f).is_file()]


def run(cmd: list[str], cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}:{os.environ['PATH']}"}
    result = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True)
    assert result.returncode == 0, f"{' '.join(cmd)} failed:\n{result.stdout}\n{result.stderr}"
    return result


def make_tiny_repo(dest: Path) -> Path:
    """A copy of the repository with params.yaml composed for `debug=tiny`, as a git repo."""
    for name in repo_files():
        target = dest / name
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(REPO_ROOT / name, target)
    for generated in ("dvc.lock", "reports"):
        path = dest / generated
        if path.is_dir():
            shutil.rmtree(path)
        elif path.exists():
            path.unlink()
    compose_params_yaml(["debug=tiny"], output=dest / "params.yaml",
                        config_dir=dest / "conf")
    run(["git", "init", "-q"], dest)
    run(["git", "add", "-A"], dest)
    run(["git", "-c", "user.email=t@t", "-c", "user.name=t", "commit", "-qm", "tiny"], dest)
    return dest


@pytest.fixture(scope="module")
def tiny_repo(tmp_path_factory):
    repo = make_tiny_repo(tmp_path_factory.mktemp("pipeline"))
    run(["dvc", "repro"], repo)
    return repo


def test_dvc_repro_writes_every_report_file(tiny_repo):
    reports = tiny_repo / "reports"
    for name in ("README.md", "config.yaml", "metrics.json", "metrics_paper.json",
                 "world/difficulty.json"):
        assert (reports / name).is_file(), name
    for stem in ("table2_recall_at_100p", "auc", "table3_inference", "ablation_paper_protocol",
                 "protocol", "invariance"):
        for ext in ("md", "csv", "tex"):
            assert (reports / "tables" / f"{stem}.{ext}").is_file(), f"{stem}.{ext}"
    figures = {p.name for p in (reports / "figures").iterdir()}
    for stem in ("fig01_weather_samples", "fig08-09_pr_route1", "fig08-09_pr_route2",
                 "fig10_auc", "fig11_reconstructions", "world_map"):
        assert {f"{stem}.png", f"{stem}.pdf"} <= figures, stem
    assert any(name.startswith("fig06_matrices") for name in figures)


def test_every_metric_is_a_number_in_range(tiny_repo):
    metrics = json.loads((tiny_repo / "reports" / "metrics.json").read_text())
    assert set(metrics) == {"route1", "route2"}
    for route, pairs in metrics.items():
        assert set(pairs) == {"foggy-rainy", "foggy-sunny", "rainy-sunny"}
        for pair, methods in pairs.items():
            assert set(methods) == {"sad", "dnn", "dnn_head", "bigan", "cmal", "cmal_untrained"}
            for method, values in methods.items():
                for key in METRICS:
                    value = values[key]
                    assert isinstance(value, float) and math.isfinite(value), \
                        (route, pair, method, key, value)
                    assert 0.0 <= value <= 1.0, (route, pair, method, key, value)


def test_a_second_repro_has_nothing_to_do(tiny_repo):
    status = run(["dvc", "status"], tiny_repo).stdout
    assert "changed" not in status, status
    out = run(["dvc", "repro"], tiny_repo).stdout
    assert "Running stage" not in out, out


def test_changing_a_seqslam_parameter_reruns_only_what_scores_with_it(tiny_repo):
    """``matching.ds`` is read by matching and everything after it, and also by the training
    monitor (validation recall in ``train_log.csv``) and the DNN layer choice: those stages
    re-run too. The dataset never does."""
    params = tiny_repo / "params.yaml"
    original = params.read_text()
    try:
        params.write_text(original.replace("  ds: 10\n", "  ds: 8\n", 1))
        out = run(["dvc", "repro", "--dry"], tiny_repo).stdout
        ran = {line.split("'")[1] for line in out.splitlines() if line.startswith("Running stage")}
        assert ran, out
        downstream = ("train@", "extract_features@", "select_protocol@", "evaluate@",
                      "evaluate_loops@", "analyse_codes", "calibrate_world", "report")
        assert all(s.startswith(downstream) for s in ran), ran
        assert "dataset" not in ran
    finally:
        params.write_text(original)


def test_re_extracting_the_same_codes_leaves_everything_but_the_report_cached(tiny_repo):
    """Timings differ on every run; they live apart from the codes (``data/timing``), so
    a re-run of a features stage that gives the same codes re-runs only the report (Table III),
    not protocol selection, evaluation or the analysis."""
    run(["dvc", "repro", "-f", "-s", "extract_features@sad"], tiny_repo)
    out = run(["dvc", "repro", "--dry"], tiny_repo).stdout
    ran = {line.split("'")[1] for line in out.splitlines() if line.startswith("Running stage")}
    assert ran == {"report"}, out
