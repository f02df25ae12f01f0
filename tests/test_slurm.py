"""Sweeps on SLURM (issue 39): the launcher's checks without a cluster, then a real one.

The first part needs no SLURM: how ``sinfo`` is read, which requests are refused, how the
queue watcher decides a job has ended, how failures become one line.

The second part (``slurm``, ``slow``) brings up a single-node cluster on this machine with
``scripts/slurm_cluster.sh`` (root, Debian's slurmctld/slurmd/munge; ``.ci/run`` installs them
and runs ``pytest -m slurm``), submits through the project's preset and stops the daemons by
PID. It skips with the reason where the packages or root are missing. Every wait is bounded.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import pytest
from omegaconf import OmegaConf

from cmal_lcd import slurm

REPO = Path(__file__).resolve().parents[1]
SINFO = "vm|debug*|2|21694|(null)\nbig|gpu|32|256000|gpu:a100:4(S:0-1)\nbig|long|32|256000|(null)\n"


def test_sinfo_rows_become_nodes_with_their_partition_and_gpus():
    nodes = slurm.parse_nodes(SINFO)
    assert [(n.name, n.partition, n.default, n.cpus, n.memory_mb, n.gpus) for n in nodes] == [
        ("vm", "debug", True, 2, 21694, 0), ("big", "gpu", False, 32, 256000, 4),
        ("big", "long", False, 32, 256000, 0)]
    assert slurm.parse_gpus("gpu:2,gpu:v100:1") == 3 and slurm.parse_gpus("(null)") == 0


@pytest.mark.parametrize("params, key", [
    ({"cpus_per_task": 4}, "hydra.launcher.cpus_per_task: asks for 4 CPUs"),
    ({"cpus_per_task": 1, "tasks_per_node": 3}, "x tasks_per_node 3"),
    ({"mem_gb": 64}, "hydra.launcher.mem_gb: asks for 65536 MB"),
    ({"gpus_per_node": 1}, "hydra.launcher.gpus_per_node"),
    ({"partition": "gpu", "gpus_per_node": 8}, "partition 'gpu'"),
    ({"partition": "cpu"}, "hydra.launcher.partition: partition 'cpu' is not on this cluster "
                           "(partitions: debug, gpu, long)"),
    ({"timeout_min": 1, "signal_delay_s": 120}, "hydra.launcher.signal_delay_s"),
])
def test_a_request_no_node_can_hold_is_refused_naming_the_key_and_the_largest_node(params, key):
    with pytest.raises(slurm.RequestError) as err:
        slurm.check_request(params, slurm.parse_nodes(SINFO))
    assert key in str(err.value) and "\n" not in str(err.value)
    if "partition:" not in key and "signal" not in key:
        assert "largest:" in str(err.value)


def test_a_request_that_fits_its_partition_passes():
    nodes = slurm.parse_nodes(SINFO)
    slurm.check_request({"cpus_per_task": 2, "mem_gb": 16, "timeout_min": 10,
                         "signal_delay_s": 60}, nodes)
    slurm.check_request({"partition": "gpu", "cpus_per_task": 8, "gpus_per_node": 4}, nodes)


def test_the_queue_watcher_ends_a_job_that_left_the_queue_and_keeps_a_running_one():
    watcher = slurm.QueueWatcher(delay_s=60)
    for job in ("7_0", "7_1", "8"):
        watcher.register_job(job)
    info = watcher.read_info(b"7_0|RUNNING\n8|CANCELLED\n")
    assert info["7_0"]["State"] == "RUNNING" and info["8"]["State"] == "CANCELLED"
    assert info["7_1"]["State"] == "LEFT_QUEUE"
    watcher._info_dict.update(info)
    assert not watcher.is_done("7_0", mode="cache")
    assert watcher.is_done("7_1", mode="cache") and watcher.is_done("8", mode="cache")


def test_submitits_error_about_a_job_becomes_one_line_with_its_state_and_log():
    cancelled = ("Job 11 (task: 0) with path /s/.submitit/11/11_0_result.pkl\nhas not produced "
                 "any output (state: CANCELLED)\nError stream produced:\n----\n"
                 "srun: error: vm: task 0: Killed\n")
    line = slurm.failure_line(RuntimeError(cancelled))
    assert line == ("SLURM job 11 ended CANCELLED without a result: srun: error: vm: task 0: "
                    "Killed (log: /s/.submitit/11/11_0_log.err)")
    raised = ("Job (task=0) failed during processing with trace:\n----\nTraceback ...\n"
              "cmal_lcd.slurm.JobFailed: data.train.dir: /x does not exist\n\nYou can check "
              "full logs with 'job.stderr(0)'\n  - /s/.submitit/3_1/3_1_0_log.err\n")
    assert slurm.job_message(RuntimeError(raised)) == "data.train.dir: /x does not exist"
    assert "(log: /s/.submitit/3_1/3_1_0_log.err)" in slurm.failure_line(RuntimeError(raised))


def test_failed_jobs_of_a_sweep_are_one_line_each_naming_overrides_message_and_log():
    from hydra.core.utils import JobReturn, JobStatus

    def job(status, value, job_id):
        result = JobReturn(overrides=["seed=1"], status=status, _return_value=value)
        result.hydra_cfg = OmegaConf.create({"hydra": {"job": {"id": job_id}}})
        return result

    results = [job(JobStatus.COMPLETED, 0.5, "4_0"),
               job(JobStatus.FAILED, slurm.JobFailed("seed: must be >= 0"), "4_1")]
    assert slurm.failed_jobs(results, folder="/s/.submitit/%j", first=10) == [
        "job #11 (seed=1), SLURM job 4_1: seed: must be >= 0 "
        "(log: /s/.submitit/4_1/4_1_0_log.err)"]


def test_a_failing_job_raises_under_submitit_and_exits_2_otherwise(monkeypatch, tmp_path):
    from cmal_lcd import app

    def broken(cfg, job_dir):
        raise FileNotFoundError(f"data.train.dir: {tmp_path} holds no frames")

    monkeypatch.setattr(app, "run_chain", broken)
    monkeypatch.setattr("hydra.core.hydra_config.HydraConfig.get",
                        lambda: SimpleNamespace(runtime=SimpleNamespace(output_dir=tmp_path)))
    monkeypatch.delenv("SUBMITIT_EXECUTOR", raising=False)
    with pytest.raises(SystemExit) as exited:
        app.run_job(OmegaConf.create({}))
    assert exited.value.code == 2
    monkeypatch.setenv("SUBMITIT_EXECUTOR", "slurm")
    with pytest.raises(slurm.JobFailed, match="holds no frames") as raised:
        app.run_job(OmegaConf.create({}))
    assert "\n" not in str(raised.value)


def test_the_shipped_preset_names_the_checked_launcher():
    preset = OmegaConf.load(REPO / "conf" / "hydra" / "launcher" / "slurm.yaml")
    module, name = preset["_target_"].rsplit(".", 1)
    launcher = getattr(__import__(module, fromlist=[name]), name)
    assert launcher.launch.__module__ == module and module.startswith("hydra_plugins.")
    assert {"partition", "timeout_min", "cpus_per_task", "mem_gb"} <= set(preset)


# ---------------------------------------------------------------------------------------------
# A real single-node cluster
# ---------------------------------------------------------------------------------------------

TINY = ["debug=tiny", "runtime.threads=1", "app.steps=[dataset,train,extract_features,"
        "select_protocol,evaluate]", "methods=[sad,cmal]", "model_names=[cmal]"]
#: Small enough for any node here (the shipped preset asks for 4 CPUs and 16 GB).
FITS = ["hydra/launcher=slurm", "hydra.launcher.cpus_per_task=1", "hydra.launcher.mem_gb=2",
        "hydra.launcher.timeout_min=20"]


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    """``SLURM_CONF`` of a single-node cluster started for this module, stopped after it."""
    if os.geteuid() != 0:
        pytest.skip("the test cluster's daemons run as root; this is not root")
    missing = [t for t in ("slurmctld", "slurmd", "munged", "sbatch", "sinfo")
               if shutil.which(t) is None]
    if missing:
        pytest.skip(f"SLURM is not installed ({', '.join(missing)} missing); "
                    f"scripts/slurm_cluster.sh install")
    folder = tmp_path_factory.mktemp("slurm")
    script = REPO / "scripts" / "slurm_cluster.sh"
    started = subprocess.run(["bash", str(script), "start", str(folder)], capture_output=True,
                             text=True, timeout=120)
    if started.returncode != 0:  # installed but broken: a failure, not a skip
        pytest.fail(f"the test cluster did not come up: {started.stderr.strip()[-400:]}")
    try:
        yield str(folder / "slurm.conf")
    finally:
        subprocess.run(["bash", str(script), "stop", str(folder)], timeout=120, check=False)


def cmal_lcd_run(args: list[str], *, conf: str | None, timeout: float) -> tuple:
    """``cmal-lcd-run ARGS`` in the checkout; (exit code, stderr, seconds)."""
    env = {**os.environ, "OMP_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1"}
    if conf:
        env["SLURM_CONF"] = conf
    start = time.monotonic()
    done = subprocess.run([sys.executable, "-m", "cmal_lcd.app", *args], cwd=REPO, env=env,
                          capture_output=True, text=True, timeout=timeout)
    return done.returncode, done.stderr, time.monotonic() - start


def squeue_states(conf: str) -> dict[str, str]:
    done = subprocess.run(["squeue", "-h", "-r", "-t", "all", "-o", "%i|%T"],
                          env={**os.environ, "SLURM_CONF": conf}, capture_output=True,
                          text=True, timeout=30, check=True)
    return dict(line.split("|") for line in done.stdout.split())


@pytest.mark.slow
@pytest.mark.slurm
def test_the_shipped_preset_is_refused_at_once_where_no_node_has_its_cpus(cluster, tmp_path):
    nodes = slurm.parse_nodes(subprocess.run(
        ["sinfo", "-h", "-N", "-o", "%N|%P|%c|%m|%G"], env={**os.environ, "SLURM_CONF": cluster},
        capture_output=True, text=True, timeout=30, check=True).stdout)
    too_many = max(n.cpus for n in nodes) + 1
    code, err, seconds = cmal_lcd_run(
        ["-m", "hydra/launcher=slurm", f"hydra.launcher.cpus_per_task={too_many}", *TINY,
         f"hydra.sweep.dir={tmp_path}/sweep"], conf=cluster, timeout=120)
    assert code == 2 and seconds < 60
    assert f"hydra.launcher.cpus_per_task: asks for {too_many} CPUs" in err
    assert not (tmp_path / "sweep" / ".submitit").exists()  # nothing was submitted


@pytest.mark.slow
@pytest.mark.slurm
def test_a_sweep_on_slurm_completes_with_a_local_runs_numbers_and_aggregates(cluster,
                                                                              tmp_path):
    sweep = tmp_path / "sweep"
    code, err, _ = cmal_lcd_run(["-m", *FITS, *TINY, "seed=0,1", f"hydra.sweep.dir={sweep}"],
                                conf=cluster, timeout=900)
    assert code == 0, err
    job_ids = sorted(p.name for p in (sweep / ".submitit").iterdir()
                     if re.fullmatch(r"\d+_\d+", p.name))
    assert len(job_ids) == 2
    # the result is written just before the job's process ends: give SLURM a moment
    deadline = time.monotonic() + 60
    while True:
        states = squeue_states(cluster)
        if all(states.get(job) == "COMPLETED" for job in job_ids) or time.monotonic() > deadline:
            break
        time.sleep(2)
    assert all(states.get(job) == "COMPLETED" for job in job_ids), states
    code, err, _ = cmal_lcd_run([*TINY, "seed=1", f"hydra.run.dir={tmp_path}/local"],
                                conf=None, timeout=900)
    assert code == 0, err
    local = json.loads((tmp_path / "local" / "metrics.json").read_text())
    assert local and json.loads((sweep / "1" / "metrics.json").read_text()) == local
    aggregated = subprocess.run([str(Path(sys.executable).parent / "cmal-lcd"), "aggregate",
                                 str(sweep), "--name", "slurm", "--out",
                                 str(tmp_path / "reports")],
                                cwd=REPO, capture_output=True, text=True, timeout=300)
    assert aggregated.returncode == 0, aggregated.stderr
    seeds = (tmp_path / "reports" / "slurm" / "table2_seeds.csv").read_text()
    assert "n_seeds" in seeds and ",2" in seeds


@pytest.mark.slow
@pytest.mark.slurm
def test_a_failing_sweep_exits_2_within_minutes_with_each_jobs_own_message(cluster, tmp_path):
    code, err, seconds = cmal_lcd_run(
        ["-m", *FITS, *TINY, "app.reuse.dataset=/nonexistent/dataset", "seed=0,1",
         f"hydra.sweep.dir={tmp_path}/sweep"], conf=cluster, timeout=300)
    assert code == 2 and seconds < 180, err
    lines = [line for line in err.splitlines() if line.startswith("cmal-lcd-run: error:")]
    assert len(lines) == 2 and all("app.reuse.dataset: /nonexistent/dataset does not exist"
                                   in line and "_log.err" in line for line in lines), err
    assert "Traceback" not in err


@pytest.mark.slow
@pytest.mark.slurm
def test_a_cancelled_job_is_reported_as_cancelled_instead_of_waited_for(cluster, tmp_path):
    env = {**os.environ, "SLURM_CONF": cluster, "OMP_NUM_THREADS": "1"}
    sweep = subprocess.Popen(
        [sys.executable, "-m", "cmal_lcd.app", "-m", *FITS, *TINY, "seed=3",
         "models.cmal.iterations=2000",  # a job that runs for minutes unless cancelled
         f"hydra.sweep.dir={tmp_path}/sweep"], cwd=REPO, env=env, stderr=subprocess.PIPE,
        text=True)
    try:
        deadline = time.monotonic() + 120
        running = []
        while not running and time.monotonic() < deadline:
            time.sleep(2)
            submitted = tmp_path / "sweep" / ".submitit"
            ours = ({p.name for p in submitted.iterdir()} if submitted.exists() else set())
            running = [job for job, state in squeue_states(cluster).items()
                       if state == "RUNNING" and job in ours]
        assert running, "the job never ran"
        subprocess.run(["scancel", running[0].split("_")[0]], env=env, timeout=30, check=True)
        _, err = sweep.communicate(timeout=180)
    finally:
        if sweep.poll() is None:
            sweep.kill()
    assert sweep.returncode == 2
    assert "ended CANCELLED without a result" in err and "_log.err" in err


@pytest.mark.slow
@pytest.mark.slurm
def test_a_timed_out_job_is_reported_as_timed_out(cluster, tmp_path):
    """timeout_min=1 with signal_delay_s=30: submitit signals the job 30 s in; with no requeue
    left (max_num_timeout 0) the job ends with submitit's own timeout message."""
    code, err, seconds = cmal_lcd_run(
        ["-m", *FITS[:-1], "hydra.launcher.timeout_min=1", "hydra.launcher.signal_delay_s=30",
         *TINY, "models.cmal.iterations=5000", "seed=4", f"hydra.sweep.dir={tmp_path}/sweep"],
        conf=cluster, timeout=300)
    assert code == 2 and seconds < 180, err
    assert "timed-out" in err and "_log.err" in err, err
