"""Sweeps on a SLURM cluster: the submitit launcher, checked before it submits and bounded after.

``hydra/launcher=slurm`` (``conf/hydra/launcher/slurm.yaml``) names the launcher
``hydra_plugins.cmal_lcd_slurm.launcher.SlurmLauncher`` (:func:`launch_checked`),
the Hydra submitit plugin's SLURM launcher with three additions (issue 39):

- **A request no node can hold is refused before submitting.** SLURM accepts an array that asks
  for more CPUs than any node of the partition has and keeps it PENDING forever
  (``PartitionConfig``); :func:`check_request` asks ``sinfo`` first and refuses in one line
  naming the key (``hydra.launcher.cpus_per_task``) and the largest node, exit 2.
- **A job that ends without a result is reported, not waited for.** submitit reads job states
  with ``sacct``; where accounting is off, that fails and submitit takes every job for still
  running, so a cancelled or killed job hung the launcher. :class:`QueueWatcher` then reads
  ``squeue`` instead: a job that has left the queue, or that SLURM lists as ended, is done, and
  submitit reports its missing result with the job's error log.
- **A failed job is one line**: the failing job, its own message (the job raises
  :class:`JobFailed` under submitit instead of exiting: :func:`cmal_lcd.app.run_job`) and its
  log folder; exit 2. The other jobs of the array run on (``scancel`` them to stop).
"""

from __future__ import annotations

import re
import subprocess
import sys
from dataclasses import dataclass
from typing import Any, Callable, Mapping, Sequence

from hydra_plugins.hydra_submitit_launcher.submitit_launcher import (
    SlurmLauncher as SubmititSlurmLauncher)
from submitit.slurm.slurm import SlurmInfoWatcher, SlurmJob

#: Seconds any SLURM client command may take here.
COMMAND_TIMEOUT_S = 30


class JobFailed(RuntimeError):
    """A sweep job's failure, raised under submitit so that it writes the job's result (an
    ``exit`` there leaves no result file for the launcher to read)."""


class RequestError(ValueError):
    """A launcher setting that no node of the partition can satisfy, naming the key."""


@dataclass(frozen=True)
class Node:
    """One row of ``sinfo -N``: a node of a partition."""

    name: str
    partition: str
    default: bool      # the partition is the cluster's default
    cpus: int
    memory_mb: int
    gpus: int


def parse_gpus(gres: str) -> int:
    """GPUs in an ``sinfo`` GRES field (``gpu:4``, ``gpu:a100:2(S:0-1)``, ``(null)``)."""
    total = 0
    for item in gres.split(","):
        parts = item.split("(")[0].split(":")
        if parts[0] == "gpu" and len(parts) >= 2 and parts[-1].isdigit():
            total += int(parts[-1])
    return total


def parse_nodes(text: str) -> list[Node]:
    """Nodes from ``sinfo -h -N -o '%N|%P|%c|%m|%G'`` output (one node per partition row)."""
    nodes = []
    for line in text.splitlines():
        fields = line.strip().split("|")
        if len(fields) != 5:
            continue
        name, partition, cpus, memory, gres = fields
        nodes.append(Node(name=name, partition=partition.rstrip("*"),
                          default=partition.endswith("*"), cpus=int(cpus),
                          memory_mb=int(re.sub(r"\D.*", "", memory) or 0),
                          gpus=parse_gpus(gres)))
    return nodes


def run_sinfo() -> str:
    """``sinfo``'s node list (:func:`parse_nodes`' format).

    Raises
    ------
    RequestError
        When ``sinfo`` is missing, fails or takes longer than :data:`COMMAND_TIMEOUT_S`.
    """
    command = ["sinfo", "-h", "-N", "-o", "%N|%P|%c|%m|%G"]
    try:
        done = subprocess.run(command, capture_output=True, text=True, check=False,
                              timeout=COMMAND_TIMEOUT_S)
    except FileNotFoundError:
        raise RequestError("hydra/launcher=slurm: sinfo not found; this machine is not a "
                           "SLURM submit host (docs/sweeps.md)") from None
    except subprocess.TimeoutExpired:
        raise RequestError(f"hydra/launcher=slurm: sinfo did not answer in "
                           f"{COMMAND_TIMEOUT_S} s; is slurmctld up?") from None
    if done.returncode != 0:
        message = (done.stderr.strip().splitlines() or ["no message"])[-1]
        raise RequestError(f"hydra/launcher=slurm: sinfo failed: {message}")
    return done.stdout


def check_request(params: Mapping[str, Any], nodes: Sequence[Node]) -> None:
    """Refuse launcher ``params`` (``hydra.launcher.*``) that no node of their partition can
    run: more CPUs per node (``cpus_per_task`` x ``tasks_per_node``), memory (``mem_gb``) or
    GPUs (``gpus_per_node``) than its largest node, an unknown partition, or a
    ``signal_delay_s`` that leaves a job less than half its ``timeout_min``.

    Raises
    ------
    RequestError
        One line naming the ``hydra.launcher.<key>`` and the largest node.
    """
    partition = params.get("partition")
    if partition is None:
        chosen = [n for n in nodes if n.default]
        where = "the default partition"
    else:
        chosen = [n for n in nodes if n.partition == str(partition)]
        where = f"partition {partition!r}"
    if not chosen:
        known = sorted({n.partition for n in nodes})
        key = "hydra.launcher.partition"
        raise RequestError(f"{key}: {where} is not on this cluster (partitions: "
                           f"{', '.join(known) or 'none'})")
    tasks = int(params.get("tasks_per_node") or 1)
    wanted = {
        "cpus_per_task": (int(params.get("cpus_per_task") or 1) * tasks, "cpus", "CPUs"),
        "mem_gb": (int(params.get("mem_gb") or 0) * 1024, "memory_mb", "MB of memory"),
        "gpus_per_node": (int(params.get("gpus_per_node") or 0), "gpus", "GPUs"),
    }
    for key, (amount, field, unit) in wanted.items():
        largest = max(chosen, key=lambda n: getattr(n, field))
        if amount > getattr(largest, field):
            per = f" x tasks_per_node {tasks}" if key == "cpus_per_task" and tasks > 1 else ""
            raise RequestError(
                f"hydra.launcher.{key}: asks for {amount} {unit}{per} per node, more than any "
                f"node of {where} has (largest: {largest.name}, {largest.cpus} CPUs, "
                f"{largest.memory_mb} MB, {largest.gpus} GPUs); SLURM would keep the jobs "
                f"pending forever. Override it, e.g. hydra.launcher.{key}="
                f"{_fitting(key, largest)}")
    timeout_s = 60 * float(params.get("timeout_min") or 0)
    delay = float(params.get("signal_delay_s") or 0)
    if timeout_s and delay > timeout_s / 2:
        raise RequestError(f"hydra.launcher.signal_delay_s: {delay:g} s before the time limit "
                           f"is more than half of timeout_min ({timeout_s:g} s): jobs would be "
                           f"signalled to stop soon after they start")


def _fitting(key: str, node: Node) -> int:
    return {"cpus_per_task": node.cpus, "mem_gb": node.memory_mb // 1024,
            "gpus_per_node": node.gpus}[key]


def accounting_available() -> bool:
    """Whether ``sacct`` answers (SLURM accounting on), within :data:`COMMAND_TIMEOUT_S`."""
    try:
        return subprocess.run(["sacct", "-n", "-X", "-j", "1"], capture_output=True,
                              timeout=COMMAND_TIMEOUT_S, check=False).returncode == 0
    except (OSError, subprocess.TimeoutExpired):
        return False


#: squeue's states of a job that will not run again.
ENDED = {"BOOT_FAIL", "CANCELLED", "COMPLETED", "DEADLINE", "FAILED", "NODE_FAIL",
         "OUT_OF_MEMORY", "PREEMPTED", "TIMEOUT"}


class QueueWatcher(SlurmInfoWatcher):
    """submitit's job watcher reading ``squeue`` instead of ``sacct`` (accounting off).

    A registered job that ``squeue`` no longer lists has left the queue: its state becomes
    ``LEFT_QUEUE``, which submitit counts as done, so a job that ended without writing its
    result (cancelled, killed, its node lost) is reported instead of waited for.
    """

    def _make_command(self) -> list[str] | None:
        if not self._registered - self._finished:
            return None
        return ["squeue", "-h", "-r", "-t", "all", "-o", "%i|%T"]

    def read_info(self, string: bytes | str) -> dict[str, dict[str, str]]:
        if not isinstance(string, str):
            string = string.decode()
        listed = {}
        for line in string.splitlines():
            job_id, _, state = line.strip().partition("|")
            if job_id:
                listed[job_id] = {"JobID": job_id, "State": state.split()[0] if state else ""}
        gone = {job_id: {"JobID": job_id, "State": "LEFT_QUEUE"}
                for job_id in self._registered - self._finished - set(listed)}
        return {**listed, **gone}


def job_message(error: BaseException) -> str:
    """The failing job's own one-line message in submitit's error text: the
    :class:`JobFailed` line when there is one, else its last non-empty line."""
    text = str(error)
    found = re.findall(r"JobFailed: (.+)", text)
    if found:
        return found[-1].strip()
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    return lines[-1] if lines else type(error).__name__


def launch_checked(launcher, job_overrides, initial_job_idx, *, sinfo: Callable[[], str] = run_sinfo):
    """:meth:`SlurmLauncher.launch`: check the request, watch the queue when accounting is off,
    submit with submitit's launcher, and turn a failed job into one line and exit 2."""
    from submitit.core.utils import FailedJobError, UncompletedJobError

    try:
        check_request(launcher.params, parse_nodes(sinfo()))
    except RequestError as exc:
        print(f"cmal-lcd-run: error: {exc}", file=sys.stderr)
        sys.exit(2)
    if not accounting_available():
        SlurmJob.watcher = QueueWatcher(delay_s=60)
    try:
        results = SubmititSlurmLauncher.launch(launcher, job_overrides, initial_job_idx)
    except (FailedJobError, UncompletedJobError) as exc:
        print(f"cmal-lcd-run: error: {failure_line(exc)}", file=sys.stderr)
        sys.exit(2)
    failed = failed_jobs(results, folder=str(launcher.params["submitit_folder"]),
                         first=initial_job_idx)
    for line in failed:
        print(f"cmal-lcd-run: error: {line}", file=sys.stderr)
    if failed:
        sys.exit(2)
    return results


def failed_jobs(results: Sequence[Any], *, folder: str, first: int = 0) -> list[str]:
    """One line per job of ``results`` (Hydra ``JobReturn``) that raised: its number, its
    overrides, its own message and its SLURM error log (``folder``: the launcher's
    ``submitit_folder``, ``%j`` standing for the job id)."""
    from hydra.core.utils import JobStatus

    from cmal_lcd.errors import one_line

    lines = []
    for number, result in enumerate(results, start=first):
        if result.status != JobStatus.FAILED:
            continue
        job_id = str(result.hydra_cfg.hydra.job.id) if result.hydra_cfg is not None else "?"
        log = f"{folder.replace('%j', job_id)}/{job_id}_0_log.err"
        lines.append(f"job #{number} ({' '.join(result.overrides)}), SLURM job {job_id}: "
                     f"{one_line(result._return_value)} (log: {log})")
    return lines


def failure_line(error: BaseException) -> str:
    """One line from submitit's error about a job: the job, its own message and its log."""
    text = str(error)
    job = re.search(r"Job \(?(?:task=\d+\) )?\(?([0-9]+(?:_[0-9]+)?)", text)
    state = re.search(r"\(state: ([A-Z_]+)\)", text)
    result = re.search(r"with path (\S+)_result\.pkl", text)
    log = re.search(r"(\S+_log\.err)", text)
    where = log.group(1) if log else (f"{result.group(1)}_log.err" if result else None)
    ended = (f"ended {state.group(1)} without a result" if state
             else "failed")
    return (f"SLURM job {job.group(1) if job else '(unknown id)'} {ended}: "
            f"{job_message(error)}" + (f" (log: {where})" if where else ""))
