"""The pipeline end to end on VPR-Bench's Corridor (``experiment=corridor``): real frames in
VPR-Bench's layout, its ``ground_truth_new.npy``, no training frames and no validation range.
Skips when ``../shared/data/vpr_bench_corridor`` is absent."""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

from cmal_lcd.config import REPO_ROOT
from subprocess_helpers import run_checked

APP = [sys.executable, "-m", "cmal_lcd.app"]
CLI = [sys.executable, "-m", "cmal_lcd.commands"]


@pytest.fixture(scope="module")
def exported(corridor_dir, tmp_path_factory) -> Path:
    """``cmal-lcd match`` on the Corridor with ``--save-descriptors``: its output folder."""
    out = tmp_path_factory.mktemp("match") / "out"
    run_checked(CLI + ["match", str(corridor_dir / "ref"), str(corridor_dir / "query"),
                       "--ground-truth", str(corridor_dir / "ground_truth_new.npy"),
                       "--save-descriptors", "--no-figures", "--out", str(out)], out.parent)
    return out


@pytest.fixture(scope="module")
def corridor_run(corridor_dir, exported, tmp_path_factory) -> Path:
    """``cmal-lcd-run experiment=corridor`` in a scratch checkout with SAD and ``sad_files``:
    the SAD descriptors match exported, as a precomputed method (one file per folder)."""
    repo = tmp_path_factory.mktemp("corridor")
    shutil.copytree(REPO_ROOT / "conf", repo / "conf")
    folder = repo / "descriptors"
    folder.mkdir()
    saved = np.load(exported / "descriptors.npz")
    np.save(folder / "ref.npy", saved["reference"])
    np.save(folder / "query.npy", saved["query"])
    node = "+extractors.sad_files"
    run_checked(APP + ["experiment=corridor", "methods=[sad,sad_files]",
                       f"data.test.dir={corridor_dir}",
                       f"data.ground_truth_file={corridor_dir / 'ground_truth_new.npy'}",
                       f"{node}._target_=cmal_lcd.features.precomputed.DescriptorFolder",
                       f"{node}.inputs=descriptors", f"{node}.metric=sad",
                       "hydra.run.dir=outputs/corridor"], repo, timeout=900)
    return repo / "outputs" / "corridor"


def test_the_pipeline_scores_every_query_of_the_ground_truth_file(corridor_run):
    meta = json.loads((corridor_run / "data" / "dataset" / "dataset.json").read_text())
    assert meta["conditions"] == ["ref", "query"]
    assert meta["pairs"] == [["corridor", "corridor/ref", "corridor/query", "ref-query"]]
    source = meta["ground_truth_source"]
    assert source["source"].startswith("VPR-Bench ground_truth_new.npy")
    assert source["n_query_without_reference"] == 0 and source["n_right_pairs"] > 111
    readme = (corridor_run / "reports" / "README.md").read_text()
    assert "VPR-Bench ground_truth_new.npy" in readme
    assert "for every method, none chosen: the dataset has no validation drives" in readme
    assert "Ablation: the paper's protocol" not in readme
    protocol = json.loads((corridor_run / "data" / "protocol" / "sad.json").read_text())
    assert protocol["fallback"] == "the dataset has no validation drives"


@pytest.mark.parametrize("method", ["sad", "sad_files"])
def test_the_pipeline_and_match_give_the_same_numbers(corridor_run, exported, method):
    """SAD computed by the pipeline, and the same codes given to it as descriptor files, score
    what ``match`` scores on the same folders and ground-truth file."""
    matched = json.loads((exported / "metrics.json").read_text())
    pipeline = json.loads((corridor_run / "reports" / "metrics.json").read_text())
    scored = pipeline["corridor"]["ref-query"][method]
    for key in ("auc_pr", "recall_at_100p", "recall_at_1", "recall_at_5"):
        assert scored[key] == pytest.approx(matched[key], abs=1e-12), key


def test_precomputed_codes_are_not_timed(corridor_run):
    table3 = (corridor_run / "reports" / "tables" / "table3_inference.md").read_text()
    assert "| sad_files | precomputed (not timed) | – | – |" in table3
