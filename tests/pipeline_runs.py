"""Helpers for the tests that run the real DVC pipeline in scratch repositories.

A scratch repository is a copy of the checkout's tracked and untracked-but-not-ignored files
(as a fresh clone plus the working changes would have them), ``params.yaml`` composed for
``debug=tiny`` plus overrides, committed to a new git repo. ``dvc`` runs from this venv.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from cmal_lcd.config import REPO_ROOT, compose_params_yaml

#: Tables measured in wall-clock time (Table III inference timings): never byte-compared.
TIMED_TABLES = ("table3_inference",)


def env() -> dict[str, str]:
    return {**os.environ, "PATH": f"{Path(sys.executable).parent}:{os.environ['PATH']}",
            "PYTHONUNBUFFERED": "1"}


def run(cmd: list[str], cwd: Path, *, check: bool = True) -> subprocess.CompletedProcess:
    result = subprocess.run(cmd, cwd=cwd, env=env(), capture_output=True, text=True)
    if check:
        assert result.returncode == 0, \
            f"{' '.join(cmd)} failed ({result.returncode}):\n{result.stdout}\n{result.stderr}"
    return result


def repo_files() -> list[str]:
    out = run(["git", "ls-files", "-co", "--exclude-standard"], REPO_ROOT).stdout.split("\n")
    return [f for f in out if f and (REPO_ROOT / f).is_file()]


def make_scratch_repo(dest: Path, overrides: tuple[str, ...] = ()) -> Path:
    """A committed copy of the repository with ``params.yaml`` for ``debug=tiny`` + overrides."""
    for name in repo_files():
        target = dest / name
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(REPO_ROOT / name, target)
    for generated in ("dvc.lock", "reports", "data", "models", "checkpoints"):
        path = dest / generated
        if path.is_dir():
            shutil.rmtree(path)
        elif path.exists():
            path.unlink()
    compose_params_yaml(["debug=tiny", *overrides], output=dest / "params.yaml",
                        config_dir=dest / "conf")
    run(["git", "init", "-q"], dest)
    run(["git", "add", "-A"], dest)
    run(["git", "-c", "user.email=t@t", "-c", "user.name=t", "commit", "-qm", "tiny"], dest)
    return dest


def clone_scratch_repo(source: Path, dest: Path) -> Path:
    """A fresh ``git clone`` of a scratch repository: the same sources and ``params.yaml``,
    no outputs, no DVC cache, no ``dvc.lock`` (so runs compare code with identical code even
    while the checkout is being edited)."""
    run(["git", "clone", "-q", str(source), str(dest)], dest.parent)
    return dest


def kill_repro_when(repo: Path, log: Path, ready, *, args: tuple[str, ...] = (),
                    timeout: float = 900.0) -> str:
    """Start ``dvc repro``, SIGKILL its whole process group once ``ready(log_text)`` holds.

    Returns the log up to the kill. Fails when the run ends before ``ready`` (nothing was
    interrupted) or after ``timeout`` seconds.
    """
    with open(log, "w") as out:
        proc = subprocess.Popen(["dvc", "repro", *args], cwd=repo, env=env(), stdout=out,
                                stderr=subprocess.STDOUT, start_new_session=True)
        deadline = time.monotonic() + timeout
        try:
            while True:
                text = log.read_text()
                if ready(text):
                    os.killpg(proc.pid, signal.SIGKILL)
                    proc.wait()
                    return text
                if proc.poll() is not None:
                    raise AssertionError(f"dvc repro ended ({proc.returncode}) before the kill "
                                         f"point:\n{text[-3000:]}")
                if time.monotonic() > deadline:
                    raise AssertionError(f"kill point not reached in {timeout} s:\n{text[-3000:]}")
                time.sleep(0.02)
        finally:
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()


def stage_started(stage: str):
    """Kill point: DVC printed ``Running stage '<stage>'`` and the stage's command line."""
    def ready(text: str) -> bool:
        head, sep, tail = text.partition(f"Running stage '{stage}'")
        return bool(sep) and "\n> " in tail
    return ready


def file_hashes(root: Path, pattern: str) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.glob(pattern)) if p.is_file()}


def comparable_outputs(repo: Path) -> dict[str, str]:
    """Hashes of every output that must be identical between two runs with the same seed.

    Dataset files, every file of the feature folders (codes and ``info.json``: the timings,
    which differ between runs, live apart in ``data/timing``), evaluation results, report
    metrics and tables (except the wall-clock Table III), and each model's weights (hashed
    tensor by tensor).
    """
    out = {}
    out.update(file_hashes(repo, "data/dataset/*"))
    out.update(file_hashes(repo, "data/features/*/*"))
    out.update(file_hashes(repo, "data/evaluation/**/*.json"))
    out.update(file_hashes(repo, "data/evaluation/*/pr/**/*.csv"))
    out.update(file_hashes(repo, "reports/metrics*.json"))
    out.update(file_hashes(repo, "reports/world/*.json"))
    out.update({k: v for k, v in file_hashes(repo, "reports/tables/*").items()
                if not Path(k).stem.startswith(TIMED_TABLES)})
    for model in sorted(repo.glob("models/*/model.pt")):
        out[str(model.relative_to(repo))] = state_dict_hash(model)
    return out


def state_dict_hash(path: Path) -> str:
    import torch

    state = torch.load(path, map_location="cpu", weights_only=False)["state_dict"]
    digest = hashlib.sha256()
    for key in sorted(state):
        digest.update(key.encode())
        digest.update(np.ascontiguousarray(state[key].detach().cpu().numpy()).tobytes())
    return digest.hexdigest()


def stray_temp_files(repo: Path) -> list[str]:
    """Left-over ``.tmp-*`` files of atomic writes in the pipeline's outputs."""
    found = []
    for top in ("data", "models", "checkpoints", "reports"):
        found += [str(p.relative_to(repo)) for p in (repo / top).rglob(".tmp-*")]
    return sorted(found)
