"""`dvc repro` runs the whole chain and `reports/` holds every promised file.

Runs the real DVC pipeline on the tiny debug config in a temporary copy of the repository
(its tracked and staged files, as a fresh clone would have them: the session's
``reference_run``, copied), then checks the reports.
"""

import json
import math
import shutil

import pytest

from pipeline_runs import run

METRICS = ("auc_pr", "auc_roc", "recall_at_100p", "recall_at_1", "single_frame_recall_at_1")


@pytest.fixture(scope="module")
def tiny_repo(reference_run, tmp_path_factory):
    """A copy of the session's finished tiny ``dvc repro`` (sources, outputs, DVC cache):
    these tests re-run stages and edit ``params.yaml``, which the shared run must not see."""
    repo = tmp_path_factory.mktemp("pipeline") / "repo"
    shutil.copytree(reference_run, repo, symlinks=True)
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
    # every series of dvc.yaml's training charts, in git (reports/), not only in the DVC cache
    import yaml

    charts = [spec for entry in yaml.safe_load((tiny_repo / "dvc.yaml").read_text())["plots"]
              for title, spec in entry.items() if "training" in title or "validation" in title]
    series = [path for spec in charts for path in spec["y"]]
    assert series and all((tiny_repo / path).is_file() for path in series), series


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
