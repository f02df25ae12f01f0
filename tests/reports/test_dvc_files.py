"""The report's DVC files: nested metrics, one summary file per method, overlaid plots."""

from __future__ import annotations

import json

import pandas as pd

from cmal_lcd.reports import dvc_files

VALUES = {"auc_pr": 0.5, "auc_roc": 0.6, "recall_at_100p": 0.25, "recall_at_1": 0.2,
          "single_frame_recall_at_1": 0.3}


def test_metrics_and_one_summary_file_per_method_stale_ones_removed(tmp_path):
    selected = {"route1": {"foggy-rainy": {"sad": VALUES, "cmal": {**VALUES, "auc_pr": 0.7}}}}
    paper = {"route1": {"foggy-rainy": {"sad": VALUES, "cmal": VALUES}}}
    (tmp_path / "summary").mkdir()
    (tmp_path / "summary" / "old_method.json").write_text("{}")
    written = dvc_files.write_metrics(tmp_path, selected=selected, paper_setting=paper,
                                      methods=["sad", "cmal"])
    assert [p.name for p in written] == ["metrics.json", "metrics_paper.json", "sad.json",
                                         "cmal.json"]
    assert json.loads((tmp_path / "metrics.json").read_text()) == selected
    assert json.loads((tmp_path / "metrics_paper.json").read_text()) == paper
    assert sorted(p.name for p in (tmp_path / "summary").iterdir()) == ["cmal.json", "sad.json"]
    assert json.loads((tmp_path / "summary" / "cmal.json").read_text())["AUC-PR"] == 0.7


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
