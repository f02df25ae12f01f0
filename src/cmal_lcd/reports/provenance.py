"""What produced a report: the git commit, the dataset kind and the config.

:func:`git_state` asks git for the commit and whether tracked files differ from it;
:func:`run_info` gathers what the README's "Run" section shows; :func:`config_text` is
``reports/config.yaml`` (the composed config headed by the commit and the dataset kind).
"""

from __future__ import annotations

import subprocess
from pathlib import Path
from typing import Sequence

from omegaconf import DictConfig, OmegaConf

from cmal_lcd.reports.readme import RunInfo, all_protocols_fell_back

#: Paths a pipeline run rewrites, never counted as a dirty work tree.
ALWAYS_IGNORED = ("dvc.lock",)


def git_state(repo_dir: Path, *, ignore: Sequence[str] = ()) -> tuple[str, bool | None]:
    """``(commit, dirty)`` of the git work tree at ``repo_dir``.

    ``dirty`` is whether tracked files differ from the commit, ignoring ``ignore`` paths (the
    report's own outputs and ``dvc.lock``, which a pipeline run rewrites). Without git or a
    commit: ``("unknown (...)", None)``.
    """
    def git(*args: str) -> str:
        return subprocess.run(["git", "-C", str(repo_dir), *args], check=True,
                              capture_output=True, text=True, timeout=30).stdout.strip()
    try:
        commit = git("rev-parse", "HEAD")
    except (OSError, subprocess.SubprocessError):
        return "unknown (not a git repository, or no commit yet)", None
    try:
        excludes = [f":(exclude){p}" for p in ignore]
        dirty = bool(git("status", "--porcelain", "--untracked-files=no", "--", ".", *excludes))
    except (OSError, subprocess.SubprocessError):
        dirty = None
    return commit, dirty


def ignored_paths(repo_dir: Path, out_dir: Path) -> list[str]:
    """:data:`ALWAYS_IGNORED` and ``out_dir`` relative to ``repo_dir`` (when inside it): the
    paths whose changes do not make the work tree dirty for :func:`git_state`."""
    ignore = list(ALWAYS_IGNORED)
    try:
        ignore.append(str(out_dir.resolve().relative_to(repo_dir.resolve())))
    except ValueError:
        pass
    return ignore


def dataset_kind(meta: dict | None, dataset_dir: Path) -> str:
    """``kind`` of ``dataset.json``, or a sentence saying it is missing."""
    return str((meta or {}).get("kind", f"unknown ({dataset_dir}/dataset.json missing)"))


def run_info(cfg: DictConfig, *, commit: str, dirty: bool | None, kind: str,
             meta: dict | None = None, protocols: dict | None = None) -> RunInfo:
    """The README's "Run" facts: seed, git state, dataset kind, the ``matching`` node, the
    ground truth of ``dataset.json`` (``meta``) and, when every method's protocol record
    (``protocols``) fell back to the paper's, why."""
    return RunInfo(seed=cfg.get("seed"), git_commit=commit, git_dirty=dirty, dataset_kind=kind,
                   matching=OmegaConf.to_container(cfg.matching, resolve=True)
                   if "matching" in cfg else {},
                   ground_truth=ground_truth_sentence(meta),
                   protocol_fallback=all_protocols_fell_back(protocols or {}),
                   **preset_fields(cfg))


def preset_fields(cfg) -> dict:
    """``presets`` and ``paper_claims`` of :class:`RunInfo` from the config's ``preset`` node
    (absent in configs written before it existed: the default)."""
    preset = cfg.get("preset") or {}
    names = tuple(str(preset[k]) for k in ("experiment", "debug") if preset.get(k))
    return {"presets": names, "paper_claims": bool(preset.get("paper_claims", True))}


def ground_truth_sentence(meta: dict | None) -> str:
    """The ground truth a dataset stored from a file or UTM names, in one sentence (its
    source, tolerance and the queries with no right reference); ``""`` for index and poses
    truth (Table I's ``D_thresh`` then says what is correct)."""
    described = (meta or {}).get("ground_truth_source")
    if not described:
        return ""
    return (f"{described.get('source')} (sha256 {described['sha256'][:12]}...); " if
            described.get("sha256") else f"{described.get('source')}; ") + (
        f"a match is correct when it is one of the query's right reference frames: tolerance "
        f"{described.get('tolerance')}, entries ignored: {described.get('n_ignored_pairs', 0)}, "
        f"queries with no right reference: {described.get('n_query_without_reference', 0)} "
        f"(these are cut to each split's frames, dataset.json ground_truth_sets); D_thresh "
        f"plays no part.")


def config_text(cfg: DictConfig, *, commit: str, dirty: bool | None, kind: str) -> str:
    """``config.yaml``: a comment header (commit, ``(dirty)``, dataset kind), then the config."""
    header = (f"# Config that produced the numbers in this folder.\n# git commit: {commit}"
              f"{' (dirty)' if dirty else ''}\n# dataset kind: {kind}\n")
    return header + OmegaConf.to_yaml(cfg, resolve=True)
