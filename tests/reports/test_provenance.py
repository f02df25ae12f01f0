"""What produced a report: git commit and dirty state, dataset kind, config.yaml's header."""

from __future__ import annotations

import shutil
import subprocess

import pytest
from omegaconf import OmegaConf

from cmal_lcd.reports import provenance


def git(repo, *args):
    return subprocess.run(["git", "-C", str(repo), "-c", "user.email=t@t", "-c", "user.name=t",
                           *args], check=True, capture_output=True, text=True).stdout.strip()


def test_outside_git_the_commit_is_unknown(tmp_path):
    commit, dirty = provenance.git_state(tmp_path)
    assert commit.startswith("unknown (not a git repository") and dirty is None


@pytest.mark.skipif(shutil.which("git") is None, reason="git not installed")
def test_git_state_ignores_untracked_files_and_the_ignored_paths(tmp_path):
    git(tmp_path, "init", "-q")
    (tmp_path / "reports").mkdir()
    for name in ("tracked.txt", "dvc.lock", "reports/README.md"):
        (tmp_path / name).write_text("a")
    git(tmp_path, "add", ".")
    git(tmp_path, "commit", "-q", "-m", "c")
    head = git(tmp_path, "rev-parse", "HEAD")
    (tmp_path / "untracked.txt").write_text("new")
    ignore = provenance.ignored_paths(tmp_path, tmp_path / "reports")
    assert ignore == ["dvc.lock", "reports"]
    assert provenance.git_state(tmp_path, ignore=ignore) == (head, False)
    (tmp_path / "dvc.lock").write_text("b")
    (tmp_path / "reports" / "README.md").write_text("b")
    assert provenance.git_state(tmp_path, ignore=ignore) == (head, False)
    (tmp_path / "tracked.txt").write_text("b")
    assert provenance.git_state(tmp_path, ignore=ignore) == (head, True)


def test_an_output_folder_outside_the_repository_is_not_ignored(tmp_path):
    assert provenance.ignored_paths(tmp_path / "repo", tmp_path / "elsewhere") == ["dvc.lock"]


def test_dataset_kind_or_why_it_is_unknown(tmp_path):
    assert provenance.dataset_kind({"kind": "nordland"}, tmp_path) == "nordland"
    assert provenance.dataset_kind(None, tmp_path) == f"unknown ({tmp_path}/dataset.json missing)"


def test_config_text_is_headed_by_commit_dirty_flag_and_kind_then_the_config():
    cfg = OmegaConf.create({"seed": 1, "a": {"b": "${seed}"}})
    text = provenance.config_text(cfg, commit="abc", dirty=True, kind="k")
    assert text.splitlines()[:3] == ["# Config that produced the numbers in this folder.",
                                     "# git commit: abc (dirty)", "# dataset kind: k"]
    assert OmegaConf.to_container(OmegaConf.create(text)) == {"seed": 1, "a": {"b": 1}}
    assert "(dirty)" not in provenance.config_text(cfg, commit="abc", dirty=None, kind="k")


def test_run_info_carries_seed_git_state_kind_and_resolved_matching():
    cfg = OmegaConf.create({"seed": 3, "d": 20, "matching": {"d_thresh": "${d}"}})
    info = provenance.run_info(cfg, commit="abc", dirty=False, kind="k")
    assert (info.seed, info.git_commit, info.git_dirty, info.dataset_kind) == (3, "abc", False,
                                                                              "k")
    assert info.matching == {"d_thresh": 20}
    assert provenance.run_info(OmegaConf.create({}), commit="c", dirty=None,
                               kind="k").matching == {}
