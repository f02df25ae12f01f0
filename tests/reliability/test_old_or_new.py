"""Catalogue: old or new outputs (docs/reliability.md, "Old or new outputs").

A stage killed with SIGKILL (its whole `dvc repro` process group) at a seeded point must leave
its outputs as the previous complete version or the new complete one, never a mix or
nothing, and `dvc repro` must then end with the outputs of an uninterrupted run.

- `report` (outs `cache: false`, `persist: true`): DVC keeps the previous report while the
  stage runs; the stage writes into `reports/.report.new-*/` and swaps its entries in once
  complete. Checked in the workspace right after each kill.
- a cached stage (`evaluate@sad`): DVC deletes its outputs before running it, so a kill leaves
  part of the new outputs; `dvc checkout --force <stage>` brings back the previous complete
  version from the cache, `dvc repro` too (the outputs `dvc.lock` names, when the stage's
  command and deps are unchanged), and a forced re-run gives the uninterrupted result.

The kill points are drawn from a fixed seed (files written so far), never from a clock: the
same points on every machine, no retries.
"""

from __future__ import annotations

import hashlib
import os
import random
import shutil
from pathlib import Path

import pytest
import yaml

from cmal_lcd.stages.report import REPORT_OUTPUTS
from pipeline_runs import (TIMED_TABLES, comparable_outputs, kill_repro_when, run,
                           stage_started, stray_temp_files)

SEED = 20261130
#: A marker that makes every entry of the previous report differ from what the next run
#: writes, so that a mix of the two is visible.
PREVIOUS = "previous run (marked by the test)"


def files(root: Path, names=None) -> list[Path]:
    """Every file under ``root`` (only under its entries ``names`` when given), hidden
    staging folders and ``.tmp-*`` files of interrupted atomic writes left out."""
    found = []
    for entry in sorted(root.iterdir()) if root.is_dir() else []:
        if entry.name.startswith(".") or (names is not None and entry.name not in names):
            continue
        found += [entry] if entry.is_file() else sorted(p for p in entry.rglob("*")
                                                        if p.is_file())
    return [p for p in found if not p.name.startswith(".tmp-")]


def hashes(root: Path, names=None) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in files(root, names)}


def report_state(repo: Path) -> dict[str, str]:
    return hashes(repo / "reports", REPORT_OUTPUTS)


def foreign_state(repo: Path) -> dict[str, str]:
    """The files of `reports/` that are not the report's (`reports/world/...`)."""
    return {k: v for k, v in hashes(repo / "reports").items()
            if k.split("/")[0] not in REPORT_OUTPUTS}


def mark_previous_report(repo: Path) -> None:
    """Make each of the report's entries distinguishable from the next run's."""
    for name in REPORT_OUTPUTS:
        path = repo / "reports" / name
        if path.is_dir():
            (path / "PREVIOUS.txt").write_text(PREVIOUS)
        else:
            with open(path, "a") as fh:
                fh.write(f"\n# {PREVIOUS}\n")


def is_complete_new_report(state: dict[str, str], reference: dict[str, str]) -> bool:
    """The files of the uninterrupted run, with its bytes wherever they are not timings."""
    def timed(name: str) -> bool:
        return name == "README.md" or Path(name).stem.startswith(TIMED_TABLES)
    return state.keys() == reference.keys() and all(
        state[k] == reference[k] for k in state if not timed(k))


def locked_out_hashes(repo: Path, stage: str) -> dict[str, str]:
    lock = yaml.safe_load((repo / "dvc.lock").read_text())["stages"].get(stage, {})
    return {o["path"]: o.get("md5") for o in lock.get("outs", [])}


def staged_files(repo: Path) -> int:
    """Files the running report has written so far (os.walk: folders renamed away while it
    looks, by the swap, are skipped, not an error)."""
    return sum(1 for staging in (repo / "reports").glob(".report.new-*")
               for _, _, names in os.walk(staging) for name in names
               if not name.startswith((".tmp-", ".staged-")))


@pytest.fixture
def repo(reference_run, tmp_path):
    """A copy of the reference run (outputs, DVC cache and `dvc.lock` included)."""
    copy = tmp_path / "repo"
    shutil.copytree(reference_run, copy, symlinks=True)
    return copy


@pytest.mark.slow
def test_report_killed_at_random_points_leaves_the_previous_or_the_new_report(
        reference_run, repo, tmp_path):
    reference = report_state(reference_run)
    foreign = foreign_state(repo)
    assert foreign, "the reference run has no reports/world"
    rng = random.Random(SEED)
    kill_points = [(f"{n} files staged", lambda text, n=n: stage_started("report")(text)
                    and staged_files(repo) >= n)
                   for n in sorted(rng.sample(range(len(reference)), 3))]
    # last: the swap is done (plots/ is swapped last), DVC has not yet recorded the stage
    plots = repo / "reports" / "plots"
    kill_points.append(("swapped in", lambda text: stage_started("report")(text)
                        and plots.is_dir() and not (plots / "PREVIOUS.txt").exists()
                        and not list((repo / "reports").glob(".report.new-*"))))
    outcomes = []
    for i, (label, ready) in enumerate(kill_points):
        if "PREVIOUS.txt" not in str(report_state(repo)):
            mark_previous_report(repo)
        previous = report_state(repo)
        kill_repro_when(repo, tmp_path / f"kill{i}.log", ready, args=("report",))
        state = report_state(repo)
        new = is_complete_new_report(state, reference)
        assert state == previous or new, f"kill at {label}: neither the previous report nor " \
            f"the new one: {sorted(set(state.items()) ^ set(previous.items()))[:6]}"
        assert foreign_state(repo) == foreign, f"kill at {label}: reports/world changed"
        outcomes.append("new" if new else "previous")
    assert outcomes[0] == "previous" and outcomes[-1] == "new", outcomes

    run(["dvc", "repro"], repo)
    assert run(["dvc", "status"], repo).stdout.count("changed") == 0
    assert is_complete_new_report(report_state(repo), reference)
    assert foreign_state(repo) == foreign
    assert list((repo / "reports").glob(".report.*")) == []
    assert stray_temp_files(repo) == []
    assert comparable_outputs(repo) == comparable_outputs(reference_run)


@pytest.mark.slow
def test_a_killed_cached_stage_is_restored_by_dvc_checkout_and_redone_by_dvc_repro(
        reference_run, repo, tmp_path):
    out = repo / "data" / "evaluation" / "sad"
    previous = hashes(out)
    locked = locked_out_hashes(repo, "evaluate@sad")
    # distinct points before the last file (after it the stage would be complete)
    first, second, third = random.Random(SEED + 1).sample(range(len(previous) - 1), 3)

    def written(n: int):
        return lambda text: stage_started("evaluate@sad")(text) and len(files(out)) >= n

    def kill_evaluate(n: int, log: str) -> dict[str, str]:
        """Kill a forced re-run of the stage; what it left (DVC deleted the previous outputs
        before running it: a part of the new ones, each file written atomically)."""
        kill_repro_when(repo, tmp_path / log, written(n), args=("-f", "-s", "evaluate@sad"))
        left = hashes(out)
        assert set(left) <= set(previous), log
        assert locked_out_hashes(repo, "evaluate@sad") == locked, log  # not recorded
        return left

    # 1. `dvc checkout --force <stage>`: the previous outputs from the cache
    kill_evaluate(first, "kill1.log")
    run(["dvc", "checkout", "--force", "evaluate@sad"], repo)
    assert hashes(out) == previous
    assert run(["dvc", "status"], repo).stdout.count("changed") == 0

    # 2. `dvc repro`: command and deps unchanged and the outputs dvc.lock names are in the
    #    cache, so DVC checks them out instead of running the stage
    if kill_evaluate(second, "kill2.log") != previous:
        again = run(["dvc", "repro"], repo)
        assert "Stage 'evaluate@sad' is cached - skipping run, checking out outputs" in \
            again.stdout, again.stdout
    assert hashes(out) == previous

    # 3. a forced re-run of the stage after the kill: the uninterrupted result
    kill_evaluate(third, "kill3.log")
    again = run(["dvc", "repro", "-f", "-s", "evaluate@sad"], repo)
    assert "Running stage 'evaluate@sad'" in again.stdout, again.stdout
    run(["dvc", "repro"], repo)
    assert run(["dvc", "status"], repo).stdout.count("changed") == 0
    assert stray_temp_files(repo) == []
    assert comparable_outputs(repo) == comparable_outputs(reference_run)
