"""Training logs through dvclive (cmal_lcd.models.live) and the charts dvc.yaml draws from them."""

import json
import shutil
import subprocess
import sys

import pytest
import yaml

from cmal_lcd.config import REPO_ROOT
from cmal_lcd.models.live import write_live_log


def rows_with(keys, iterations=(0, 25, 50)):
    """One logged row per iteration holding every key (value = iteration / 100 + key index)."""
    return [{"iteration": it, **{k: it / 100 + i for i, k in enumerate(keys)}}
            for it in iterations]


def training_charts() -> dict:
    """dvc.yaml's training charts: ``{title: definition}``."""
    plots = yaml.safe_load((REPO_ROOT / "dvc.yaml").read_text())["plots"]
    return {title: spec for entry in plots for title, spec in entry.items()
            if "training" in title or "validation" in title}


def chart_series(path: str) -> tuple[str, str]:
    """``reports/plots/training/<model>/<key>.tsv`` -> (``<model>``, ``<key>``): the model whose
    dvclive series the report copies there (cmal_lcd.reports.dvc_files.write_training_plots)."""
    prefix = "reports/plots/training/"
    assert path.startswith(prefix), path
    model, key = path.removeprefix(prefix).removesuffix(".tsv").split("/", 1)
    return model, key


def write_series(root, keys_of: dict) -> None:
    """Each model's dvclive log under ``root/models/<model>``, then the report's copy of its
    series under ``root/reports/plots``."""
    from cmal_lcd.reports.dvc_files import write_training_plots

    for model, keys in keys_of.items():
        write_live_log(root / "models" / model, rows_with(keys), {})
    write_training_plots(root / "reports" / "plots",
                         {m: root / "models" / m / "train_log.csv" for m in keys_of})


def test_a_rewrite_replaces_the_previous_folder_instead_of_appending(tmp_path):
    write_live_log(tmp_path, rows_with(["D/loss"], (0, 25, 50)), {"iterations": 50})
    write_live_log(tmp_path, rows_with(["D/loss"], (0, 25)), {"iterations": 25})
    series = (tmp_path / "dvclive" / "plots" / "metrics" / "D" / "loss.tsv").read_text().split()
    assert series[::2] == ["step", "0", "25"]
    assert yaml.safe_load((tmp_path / "dvclive" / "params.yaml").read_text()) == {
        "iterations": 25}


def test_every_series_a_dvc_yaml_training_chart_reads_is_a_file_the_logger_writes(tmp_path):
    charts = training_charts()
    assert set(charts) == {"CMAL training", "CMAL validation", "BiGAN training",
                           "BiGAN validation"}
    for spec in charts.values():
        assert spec["x"] == "step"
        for path, field in spec["y"].items():
            model, key = chart_series(path)
            write_series(tmp_path, {model: [key]})
            header = (tmp_path / path).read_text().splitlines()[0].split("\t")
            assert header == ["step", field], path


def test_dvc_plots_show_draws_the_training_charts_offline(tmp_path):
    if shutil.which("git") is None:
        pytest.skip("git not installed")
    dvc = [sys.executable, "-m", "dvc"]
    subprocess.run(["git", "init", "-q"], cwd=tmp_path, check=True)
    subprocess.run(dvc + ["init", "-q"], cwd=tmp_path, check=True)
    charts = training_charts()
    keys_of = {}  # every key each model's charts read, written in one go
    for spec in charts.values():
        for path in spec["y"]:
            model, key = chart_series(path)
            keys_of.setdefault(model, []).append(key)
    write_series(tmp_path, keys_of)
    shutil.rmtree(tmp_path / "models")  # a fresh clone has no models/ (DVC cache)
    (tmp_path / "dvc.yaml").write_text(yaml.safe_dump(
        {"plots": [{title: spec} for title, spec in charts.items()]}))
    shown = subprocess.run(dvc + ["plots", "show", "--json"], cwd=tmp_path, check=True,
                           capture_output=True, text=True)
    data = json.loads(shown.stdout)["data"]
    for title, spec in charts.items():
        assert title in data, title
        [chart] = data[title]
        points = chart["content"]["data"]["values"]
        assert len(points) == 3 * len(spec["y"]), title  # 3 steps of every series
        assert not json.loads(shown.stdout).get("errors"), shown.stdout[-2000:]


def test_outside_a_dvc_repository_nothing_is_written_and_no_dvc_is_initialised(tmp_path,
                                                                              monkeypatch):
    """dvclive would `dvc init` a git work tree without DVC; the writer stays out of it."""
    if shutil.which("git") is None:
        pytest.skip("git not installed")
    subprocess.run(["git", "init", "-q"], cwd=tmp_path, check=True)
    monkeypatch.chdir(tmp_path)
    assert write_live_log(tmp_path / "model", rows_with(["D/loss"]), {}) is None
    assert sorted(p.name for p in tmp_path.iterdir()) == [".git"]
