"""The report's DVC files: nested metrics, the headline DVC metric, one summary file per
method, overlaid plots."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest
import yaml

from cmal_lcd.reports import dvc_files

REPO_ROOT = Path(__file__).resolve().parents[2]
#: The methods of the default run (params.yaml), the widest names included.
DEFAULT_METHODS = ["sad", "dnn", "dnn_head", "bigan", "cmal", "cmal_untrained"]

VALUES = {"auc_pr": 0.5, "auc_roc": 0.6, "recall_at_100p": 0.25, "recall_at_1": 0.2,
          "single_frame_recall_at_1": 0.3}


def test_metrics_and_one_summary_file_per_method_stale_ones_removed(tmp_path):
    selected = {"route1": {"foggy-rainy": {"sad": VALUES, "cmal": {**VALUES, "auc_pr": 0.7}}}}
    paper = {"route1": {"foggy-rainy": {"sad": VALUES, "cmal": VALUES}}}
    (tmp_path / "summary").mkdir()
    (tmp_path / "summary" / "old_method.json").write_text("{}")
    written = dvc_files.write_metrics(tmp_path, selected=selected, paper_setting=paper,
                                      methods=["sad", "cmal"])
    assert [p.name for p in written] == ["metrics.json", "metrics_paper.json", "summary.json",
                                         "sad.json", "cmal.json"]
    assert json.loads((tmp_path / "metrics.json").read_text()) == selected
    assert json.loads((tmp_path / "metrics_paper.json").read_text()) == paper
    assert sorted(p.name for p in (tmp_path / "summary").iterdir()) == ["cmal.json", "sad.json"]
    assert json.loads((tmp_path / "summary" / "cmal.json").read_text())["AUC-PR"] == 0.7
    assert json.loads((tmp_path / "summary.json").read_text()) == {
        "R100P": {"sad": 0.25, "cmal": 0.25}}


def test_the_headline_is_one_key_of_every_method_none_kept():
    summary = {"sad": {"R@100P": 0.8, "AUC-PR": 0.9}, "cmal": {"R@100P": None, "AUC-PR": 0.7}}
    assert dvc_files.headline(summary) == {"R100P": {"sad": 0.8, "cmal": None}}
    assert dvc_files.headline(summary, key="AUC-PR", name="AUCPR") == {
        "AUCPR": {"sad": 0.9, "cmal": 0.7}}


def dvc(args: list[str], cwd: Path) -> str:
    env = {**os.environ, "COLUMNS": "120", "PATH": f"{Path(sys.executable).parent}:"
                                                   f"{os.environ['PATH']}"}
    result = subprocess.run([sys.executable, "-m", "dvc", *args], cwd=cwd, env=env,
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    return result.stdout


@pytest.mark.skipif(shutil.which("git") is None, reason="needs git for a scratch DVC repository")
def test_dvc_metrics_show_and_exp_show_fit_a_120_column_terminal(tmp_path):
    """The report's files under the real dvc.yaml declarations of the report stage, in a scratch
    repository: `dvc metrics show`, `dvc exp show` and `dvc metrics show -R reports/summary`
    print lines of at most 120 columns with every value in full (no column folded to "…")."""
    report_stage = yaml.safe_load((REPO_ROOT / "dvc.yaml").read_text())["stages"]["report"]
    spec = {"stages": {"report": {"cmd": "true", "outs": report_stage["outs"],
                                  "metrics": report_stage["metrics"]}}}
    (tmp_path / "dvc.yaml").write_text(yaml.safe_dump(spec))
    values = {**VALUES, "recall_at_5": 0.5}
    selected = {"route1": {"foggy-rainy": {m: values for m in DEFAULT_METHODS}}}
    dvc_files.write_metrics(tmp_path / "reports", selected=selected, paper_setting=selected,
                            methods=DEFAULT_METHODS)
    subprocess.run(["git", "init", "-q"], cwd=tmp_path, check=True)
    dvc(["init", "-q"], tmp_path)
    subprocess.run(["git", "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qam", "x",
                    "--allow-empty"], cwd=tmp_path, check=True)
    for args in (["metrics", "show"], ["exp", "show", "--no-pager"],
                 ["metrics", "show", "-R", "reports/summary"]):
        out = dvc(args, tmp_path)
        lines = [line for line in out.splitlines() if line.strip()]
        assert lines and max(len(line) for line in lines) <= 120, (args, out)
        assert "…" not in out, (args, out)
        for method in DEFAULT_METHODS:
            assert method in out, (args, method, out)


def curve() -> pd.DataFrame:
    return pd.DataFrame({"recall": [0.0, 0.5, 1.0], "precision": [1.0, 1.0, 0.5],
                         "threshold": [0.1, 0.2, 0.3]})


def test_roc_counts_come_from_the_selected_evaluation_when_it_has_both():
    curves = {"route1": {"foggy-rainy": {"sad": curve(), "cmal": curve()}}}
    evaluations = {
        "sad": {"route1": {"foggy-rainy": {"selected": {"n_positive": 4, "n_scored": 9}}}},
        "cmal": {"route1": {"foggy-rainy": {"selected": {"n_positive": 4}}}}}
    assert dvc_files.roc_counts(curves, evaluations) == {
        "route1": {"foggy-rainy": {"sad": {"n_positive": 4, "n_scored": 9}}}}


def test_plots_files_replace_earlier_ones(tmp_path):
    stale = tmp_path / "pr" / "route9" / "old.csv"
    stale.parent.mkdir(parents=True)
    stale.write_text("x")
    curves = {"route1": {"foggy-rainy": {"sad": curve()}}}
    evaluations = {"sad": {"route1": {"foggy-rainy": {"selected": {"n_positive": 4,
                                                                   "n_scored": 9}}}}}
    dvc_files.write_plots_files(tmp_path, curves, evaluations=evaluations, labels={"sad": "SAD"})
    assert not stale.exists()
    overlay = pd.read_csv(tmp_path / "pr" / "route1" / "foggy-rainy.csv")
    assert set(overlay["method"]) == {"SAD"}
    assert (tmp_path / "roc" / "route1" / "foggy-rainy.csv").is_file()
