"""A method in one file: a user's module under ``src/`` plus one ``extractors`` node in
``conf/config.yaml`` of a checkout, and nothing else edited, runs through the whole chain
(Table II, the report) and through ``cmal-lcd match``."""

from __future__ import annotations

import importlib.util
import json
import re
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import yaml
import pytest

from cmal_lcd.config import REPO_ROOT, compose
from subprocess_helpers import run_checked

APP = [sys.executable, "-m", "cmal_lcd.app"]
CLI = [sys.executable, "-m", "cmal_lcd.commands"]



def recipe_blocks() -> tuple[str, str]:
    """The user's file and config node exactly as docs/architecture.md shows them ("Your own
    method"): the test runs the documented recipe, so the docs cannot drift from what works."""
    text = (REPO_ROOT / "docs" / "architecture.md").read_text()
    section = text.split("### Your own method", 1)[1].split("\n### ", 1)[0]
    blocks: dict[str, str] = {}
    for kind, text in re.findall(r"```(python|yaml)\n(.*?)```", section, flags=re.S):
        blocks.setdefault(kind, text)  # the recipe's own: the first of each
    return textwrap.dedent(blocks["python"]), textwrap.dedent(blocks["yaml"])


USER_FILE, USER_NODE = recipe_blocks()


@pytest.fixture(scope="module")
def checkout(tmp_path_factory) -> Path:
    """A scratch checkout: the project's conf/ with the user's node, and the user's file."""
    repo = tmp_path_factory.mktemp("user_method")
    shutil.copy2(REPO_ROOT / ".gitignore", repo / ".gitignore")
    shutil.copytree(REPO_ROOT / "conf", repo / "conf")
    config = repo / "conf" / "config.yaml"
    text = config.read_text()
    anchor = "\n# Derived from `methods`, never set"  # where the docs say the node goes
    assert text.count(anchor) == 1 and "\nextractors:" not in text
    config.write_text(text.replace(anchor, "\n" + USER_NODE + anchor))
    (repo / "src").mkdir()
    (repo / "src" / "tiny_images.py").write_text(USER_FILE)
    run_checked(["git", "init", "-q"], repo)
    run_checked(["git", "add", "-A"], repo)
    run_checked(["git", "-c", "user.email=t@t", "-c", "user.name=t", "commit", "-qm", "s"],
                repo)
    return repo


def user_function(checkout: Path):
    spec = importlib.util.spec_from_file_location("tiny_images_test",
                                                  checkout / "src" / "tiny_images.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.tiny_images


def test_the_node_adds_the_method_and_its_stage_inputs(checkout, monkeypatch):
    monkeypatch.chdir(checkout)
    cfg = compose(config_dir=checkout / "conf")
    assert list(cfg.methods) == ["sad", "dnn", "dnn_head", "bigan", "cmal", "cmal_untrained",
                                 "tiny"]
    assert dict(cfg.feature_inputs.tiny) == {"file": "src/tiny_images.py",
                                             "params": ["extractors.tiny", *["runtime.threads"] * 2]}


def test_the_chain_puts_the_method_in_table2_and_the_report(checkout):
    run_checked(APP + ["debug=tiny", "methods=[sad,tiny]", "hydra.run.dir=outputs/tiny"],
                checkout, timeout=900)
    job = checkout / "outputs" / "tiny"
    info = json.loads((job / "data" / "features" / "tiny" / "info.json").read_text())
    assert (info["label"], info["metric"], info["dim"]) == ("Tiny images (8x8)",
                                                             "sqeuclidean", 64)
    table2 = (job / "reports" / "tables" / "table2_recall_at_100p.md").read_text()
    rows = [line for line in table2.splitlines() if line.startswith("| Tiny images (8x8) |")]
    assert len(rows) == 1 and rows[0].count("%") == 6  # a figure for every route and pair
    assert "Tiny images (8x8)" in (job / "reports" / "README.md").read_text()
    assert (job / "data" / "evaluation" / "tiny").is_dir()


def write_frames(folder: Path, images: np.ndarray) -> None:
    folder.mkdir()
    for i, image in enumerate(images):
        cv2.imwrite(str(folder / f"{i:03d}.png"), cv2.cvtColor(image, cv2.COLOR_RGB2BGR))


def test_match_runs_the_method_from_the_checkouts_conf(checkout, tmp_path):
    rng = np.random.default_rng(3)
    places = rng.integers(0, 256, (40, 24, 32, 3), dtype=np.uint8)
    query = np.clip(places * 0.8 + rng.normal(0, 6, places.shape), 0, 255).astype(np.uint8)
    write_frames(tmp_path / "ref", places)
    write_frames(tmp_path / "query", query)
    out = tmp_path / "out"
    result = subprocess.run(CLI + ["match", str(tmp_path / "ref"), str(tmp_path / "query"),
                                   "--features", "tiny", "--ds", "5", "--save-descriptors",
                                   "--no-figures", "--out", str(out)],
                            cwd=checkout, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr
    metrics = json.loads((out / "metrics.json").read_text())
    assert (metrics["params"]["features"], metrics["params"]["label"]) == ("tiny",
                                                                          "Tiny images (8x8)")
    saved = np.load(out / "descriptors.npz")
    tiny = user_function(checkout)
    np.testing.assert_allclose(saved["reference"], tiny(places), rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(saved["query"], tiny(query), rtol=1e-5, atol=1e-6)


def test_loops_runs_the_method_from_the_checkouts_conf(checkout, tmp_path):
    rng = np.random.default_rng(4)
    places = rng.integers(0, 256, (30, 24, 32, 3), dtype=np.uint8)
    lap2 = np.clip(places * 0.9 + rng.normal(0, 5, places.shape), 0, 255).astype(np.uint8)
    write_frames(tmp_path / "laps", np.concatenate([places, lap2]))
    result = subprocess.run(CLI + ["loops", str(tmp_path / "laps"), "--features", "tiny",
                                   "--ds", "5", "--exclude-frames", "20",
                                   "--out", str(tmp_path / "out")],
                            cwd=checkout, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr
    loops = pd.read_csv(tmp_path / "out" / "loops.csv")
    lap2 = loops[loops.query_frame >= 35]  # past the look-back of the first ds frames of lap 2
    assert len(lap2) == 25 and (lap2.matched_frame == lap2.query_frame - 30).mean() >= 0.9


def test_match_names_the_configured_methods_for_an_unknown_one(checkout, tmp_path):
    result = subprocess.run(CLI + ["match", str(tmp_path), str(tmp_path), "--features", "vlad",
                                   "--out", str(tmp_path / "out")],
                            cwd=checkout, capture_output=True, text=True, timeout=300)
    assert result.returncode == 2
    assert "'vlad'" in result.stderr and "'tiny'" in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "out").exists()


def test_dvc_gives_the_method_its_stages_with_its_file_and_node(checkout, tmp_path,
                                                                 monkeypatch):
    from cmal_lcd.config import compose_params_yaml
    from cmal_lcd.stages import extract_features, stage_params
    from dvc_stages import resolved

    monkeypatch.chdir(checkout)
    params = compose_params_yaml(config_dir=checkout / "conf", output=tmp_path / "params.yaml")
    pipeline = resolved(tmp_path / "dvc", params_yaml=params.read_text())
    stage = pipeline.stages["extract_features@tiny"]
    assert "src/tiny_images.py" in stage.deps
    assert stage.params == frozenset(stage_params(extract_features, "tiny",
                                                  yaml.safe_load(params.read_text())))
    assert "extractors.tiny" in stage.params
    assert {"select_protocol@tiny", "evaluate@tiny", "report"} <= pipeline.downstream[
        "extract_features@tiny"]
