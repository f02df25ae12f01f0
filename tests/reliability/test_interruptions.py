"""Catalogue: interruptions (docs/reliability.md, "Interruptions").

What a user does after a crash or a `kill -9` is run `dvc repro` again. These tests SIGKILL a
real `dvc repro` of the tiny pipeline (its whole process group) while a stage runs, run
`dvc repro` again, and require that

- the second run completes (DVC's stale run lock of a killed process does not block it);
- every output equals the uninterrupted reference run's (same seed): dataset, codes,
  evaluation and report metrics and tables (except the wall-clock Table III), model weights;
- no half-written file is ever taken as done: the killed stage is not recorded in `dvc.lock`
  and the outputs hold no `.tmp-*` file of an interrupted atomic write;
- a killed training resumes from its last checkpoint (the log says so) and ends with the
  weights of an uninterrupted training.
"""

from __future__ import annotations

import re
import shutil
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
import yaml

from cmal_lcd.stages.report import REPORT_OUTPUTS
from pipeline_runs import (
    comparable_outputs,
    env,
    kill_repro_when,
    run,
    stage_started,
    state_dict_hash,
    stray_temp_files,
)

TRAIN_ITERATIONS = 40
CHECKPOINT_EVERY = 5


def locked_stages(repo: Path) -> set[str]:
    lock = repo / "dvc.lock"
    return set(yaml.safe_load(lock.read_text())["stages"]) if lock.exists() else set()


def test_atomic_write_killed_mid_write_leaves_the_previous_file(tmp_path):
    """The guarantee every stage relies on: SIGKILL inside a write never truncates the target."""
    target = tmp_path / "codes.npy"
    np.save(target, np.arange(5))
    script = textwrap.dedent(f"""
        import os, signal
        import numpy as np
        from cmal_lcd.io import atomic_path
        with atomic_path({str(target)!r}) as tmp:
            with open(tmp, "wb") as fh:
                fh.write(b"half of a new file")
                fh.flush()
                os.kill(os.getpid(), signal.SIGKILL)
    """)
    result = subprocess.run([sys.executable, "-c", script], capture_output=True)
    assert result.returncode == -signal.SIGKILL
    np.testing.assert_array_equal(np.load(target), np.arange(5))
    leftovers = [p.name for p in tmp_path.iterdir() if p.name != "codes.npy"]
    assert len(leftovers) == 1 and leftovers[0].startswith(".tmp-codes.npy.")


@pytest.fixture(scope="module")
def longer_training(reference_run, tmp_path_factory):
    """A copy of the reference run whose CMAL trains for 40 iterations, checkpoint every 5."""
    repo = tmp_path_factory.mktemp("resume") / "repo"
    shutil.copytree(reference_run, repo, symlinks=True)
    shutil.rmtree(repo / "checkpoints" / "cmal", ignore_errors=True)
    params = repo / "params.yaml"
    cfg = yaml.safe_load(params.read_text())
    cfg["models"]["cmal"]["iterations"] = TRAIN_ITERATIONS
    cfg["models"]["cmal"]["checkpoint_every"] = CHECKPOINT_EVERY
    params.write_text(yaml.safe_dump(cfg, sort_keys=False))
    return repo


def test_killed_training_resumes_from_its_checkpoint_with_identical_weights(longer_training,
                                                                           tmp_path):
    repo = longer_training

    def after_a_checkpoint(text: str) -> bool:
        done = [int(n) for n in re.findall(rf"cmal (\d+)/{TRAIN_ITERATIONS} ", text)]
        return bool(done) and max(done) >= 2 * CHECKPOINT_EVERY + 2

    killed_log = kill_repro_when(repo, tmp_path / "killed.log", after_a_checkpoint,
                                 args=("train@cmal",))
    assert "cmal: training from scratch" in killed_log
    assert "changed" in run(["dvc", "status", "train@cmal"], repo).stdout
    assert (repo / "checkpoints" / "cmal" / "last.pt").is_file()

    second = run(["dvc", "repro", "train@cmal"], repo)
    resumed = second.stdout + second.stderr
    match = re.search(r"cmal: resuming from \S*checkpoints/cmal/last\.pt at iteration (\d+)",
                      resumed)
    assert match, resumed
    assert int(match.group(1)) >= 2 * CHECKPOINT_EVERY
    assert int(match.group(1)) % CHECKPOINT_EVERY == 0
    first_resumed = re.search(rf"cmal (\d+)/{TRAIN_ITERATIONS} ", resumed)
    assert int(first_resumed.group(1)) == int(match.group(1)) + 1

    # the same training, uninterrupted, with the stage's own command into scratch folders
    subprocess.run([sys.executable, "-m", "cmal_lcd.stages.train", "--params", "params.yaml",
                    "--model", "cmal", "--dataset", "data/dataset",
                    "--out", str(tmp_path / "straight"),
                    "--checkpoints", str(tmp_path / "straight_ckpt")],
                   cwd=repo, env={**env(), "PYTHONPATH": "src"}, check=True,
                   capture_output=True)
    assert state_dict_hash(repo / "models" / "cmal" / "model.pt") == \
        state_dict_hash(tmp_path / "straight" / "model.pt")
    assert (repo / "models" / "cmal" / "train_log.csv").read_bytes() == \
        (tmp_path / "straight" / "train_log.csv").read_bytes()
    assert stray_temp_files(repo) == []


@pytest.mark.slow
def test_pipeline_killed_in_every_kind_of_stage_ends_identical_to_an_uninterrupted_run(
        reference_run, tmp_path_factory, tmp_path):
    """One scratch run, SIGKILLed in turn during dataset rendering, training, feature
    extraction and report writing, each time followed by `dvc repro`."""
    from pipeline_runs import clone_scratch_repo

    repo = clone_scratch_repo(reference_run, tmp_path_factory.mktemp("interrupted") / "repo")

    def rendering(text: str) -> bool:
        return stage_started("dataset")(text) and "rendered train" in text

    def training(text: str) -> bool:
        return stage_started("train@cmal")(text) and re.search(r"cmal [2-9]/", text) is not None

    def report_writing(text: str) -> bool:  # the report writes into reports/.report.new-*/
        return stage_started("report")(text) and \
            any((repo / "reports").glob(".report.new-*/metrics.json"))

    kill_points = [("dataset", rendering), ("train@cmal", training),
                   ("extract_features@cmal", stage_started("extract_features@cmal")),
                   ("report", report_writing)]
    for i, (stage, ready) in enumerate(kill_points):
        kill_repro_when(repo, tmp_path / f"kill{i}.log", ready)
        assert stage not in locked_stages(repo), f"killed stage {stage} recorded as done"
    # the report never completed in this run: none of its entries is in reports/ (old = none)
    assert not any((repo / "reports" / name).exists() for name in REPORT_OUTPUTS)

    final = run(["dvc", "repro"], repo)
    assert "Running stage 'report'" in final.stdout
    assert run(["dvc", "status"], repo).stdout.count("changed") == 0
    assert stray_temp_files(repo) == []
    assert list((repo / "reports").glob(".report.*")) == []
    assert comparable_outputs(repo) == comparable_outputs(reference_run)
