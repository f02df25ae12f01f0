"""Reading a Hydra sweep folder: its jobs, their overrides, metrics, validation choices,
invariance and training records.

A sweep folder (``multirun/<date>/<time>/``) holds one sub-folder per job with Hydra's
``.hydra/overrides.yaml`` and the app's flat ``metrics.json``
(``{"route/pair/method/metric": value}``). :func:`collect_sweep` makes one row per job and
metric entry; the statistics over seeds are in :mod:`cmal_lcd.reports.seed_statistics`.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

logger = logging.getLogger(__name__)


METRICS = ("auc_pr", "auc_roc", "recall_at_100p", "recall_at_1", "single_frame_recall_at_1")

def parse_overrides(overrides: list[str]) -> dict[str, str]:
    """``["seed=1", "matching.ds=5"]`` -> ``{"seed": "1", "matching.ds": "5"}``."""
    parsed = {}
    for item in overrides:
        key, sep, value = item.partition("=")
        if not sep:
            raise ValueError(f"override {item!r}: expected key=value")
        parsed[key.lstrip("+~")] = value
    return parsed

def collect_sweep(sweep_dir: str | Path, *, variant: str = "selected") -> pd.DataFrame:
    """One row per (job, route, pair, method) with the job's overrides and the five metrics.

    ``variant``: ``selected`` (the job's ``metrics.json``: each method's protocol chosen on
    validation), or another variant of the evaluate stage's files
    (``data/evaluation/<method>/metrics.json``: ``paper``, or ``strict``, the selected matches
    at ``matching.d_thresh_strict``).

    Raises
    ------
    FileNotFoundError
        When ``sweep_dir`` is not a folder, or has no job with ``.hydra/overrides.yaml`` and
        ``metrics.json``.
    """
    sweep_dir = Path(sweep_dir)
    if not sweep_dir.is_dir():
        raise FileNotFoundError(f"{sweep_dir}: no such sweep folder (a `cmal-lcd-run -m ...` "
                                f"output, e.g. multirun/<date>/<time>)")
    rows = []
    for job in sweep_jobs(sweep_dir):
        overrides = parse_overrides(yaml.safe_load((job / ".hydra/overrides.yaml").read_text())
                                    or [])
        metrics_file = job / "metrics.json"
        if not metrics_file.is_file():
            logger.warning("%s: no metrics.json (the job failed or is still running); skipped",
                           job)
            continue
        entries = (job_metrics(metrics_file) if variant == "selected"
                   else variant_metrics(job / "data" / "evaluation", variant))
        for (route, pair, method), values in entries.items():
            rows.append({"job": job.name, **overrides, "route": route, "pair": pair,
                         "method": method, **{m: values.get(m) for m in METRICS}})
    if not rows:
        raise FileNotFoundError(f"{sweep_dir}: no finished job (a sub-folder with "
                                ".hydra/overrides.yaml and metrics.json)")
    table = pd.DataFrame(rows)
    for column in table.columns:
        if column not in METRICS and column not in ("route", "pair", "method"):
            converted = pd.to_numeric(table[column], errors="coerce")
            if converted.notna().all():
                table[column] = converted
    return table

def job_metrics(path: Path) -> dict:
    """``{(route, pair, method): {metric: value}}`` of a job's flat ``metrics.json``."""
    entries: dict = {}
    for key, value in json.loads(path.read_text()).items():
        route, pair, method, metric = key.split("/")
        entries.setdefault((route, pair, method), {})[metric] = value
    return entries

def variant_metrics(evaluation_dir: Path, variant: str) -> dict:
    """``{(route, pair, method): {metric: value}}`` of one variant of every method's
    ``<evaluation_dir>/<method>/metrics.json`` (methods without it are left out).

    Raises
    ------
    ValueError
        When no method's file holds ``variant`` (naming the folder).
    """
    entries: dict = {}
    for path in sorted(evaluation_dir.glob("*/metrics.json")):
        for route, pairs in json.loads(path.read_text()).items():
            for pair, variants in pairs.items():
                if variant in variants:
                    entries[(route, pair, path.parent.name)] = variants[variant]
    if not entries:
        raise ValueError(f"{evaluation_dir}: no method was evaluated with variant {variant!r}")
    return entries

#: Overrides that say how a job ran, not what it measured: which steps ran and which folders
#: were reused (``app.*``), Hydra's own settings, and which methods the job evaluated. Jobs
#: differing only in these are the same experiment (e.g. a seed taken from ``dvc repro``'s
#: outputs through ``app.reuse``, or a seed run without BiGAN), so they are pooled over seeds.
PLUMBING_PREFIXES = ("app.", "hydra.")

PLUMBING_KEYS = ("methods",)

def is_plumbing_override(column: str) -> bool:
    """Whether an override column is run plumbing (:data:`PLUMBING_PREFIXES`), not a setting."""
    return column in PLUMBING_KEYS or column.startswith(PLUMBING_PREFIXES)

def evaluated_test_routes(job: Path) -> bool:
    """Whether a job evaluated the test routes: its ``metrics.json`` exists and has entries (a
    job whose steps stopped at ``select_protocol`` writes an empty one)."""
    path = Path(job) / "metrics.json"
    if not path.is_file():
        return False
    try:
        return bool(json.loads(path.read_text()))
    except json.JSONDecodeError:
        return False

def sweep_jobs(sweep_dir: Path) -> list[Path]:
    """The job folders of a Hydra sweep (those with ``.hydra/overrides.yaml``), in job order:
    numbered folders by number (``2`` before ``10``), then any others by name."""
    jobs = (p.parent.parent for p in Path(sweep_dir).glob("*/.hydra/overrides.yaml"))
    return sorted(jobs, key=lambda job: (not job.name.isdigit(),
                                         int(job.name) if job.name.isdigit() else 0, job.name))

def jobs_and_overrides(sweep_dir: Path, *, finished: bool = True) -> list[tuple[Path, dict[str, str]]]:
    """Jobs of a sweep and their overrides, in job order (:func:`sweep_jobs`); with
    ``finished``, only those that evaluated the test routes (:func:`evaluated_test_routes`)."""
    jobs = []
    for job in sweep_jobs(sweep_dir):
        overrides_file = job / ".hydra" / "overrides.yaml"
        if not finished or evaluated_test_routes(job):
            jobs.append((job, parse_overrides(yaml.safe_load(overrides_file.read_text()) or [])))
    return jobs

def job_setting(job: Path, key: str):
    """A dotted key of a job's composed config (``.hydra/config.yaml``, interpolations such as
    ``${models.cmal.iterations}`` resolved), or None if absent."""
    from omegaconf import OmegaConf

    path = Path(job) / ".hydra" / "config.yaml"
    if not path.is_file():
        return None
    value = OmegaConf.select(OmegaConf.load(path), key, default=None)
    return OmegaConf.to_container(value, resolve=True) if OmegaConf.is_config(value) else value

def job_models_dir(job: Path) -> Path:
    """The models folder a job used: its own, or ``app.reuse.models`` (a relative path is
    relative to the folder the job was launched from, Hydra's ``runtime.cwd``)."""
    reused = job_setting(job, "app.reuse.models")
    if reused is None:
        return Path(job) / "models"
    reused = Path(reused)
    hydra_file = Path(job) / ".hydra" / "hydra.yaml"
    if not reused.is_absolute() and hydra_file.is_file():
        cwd = (yaml.safe_load(hydra_file.read_text()) or {}).get("hydra", {}).get(
            "runtime", {}).get("cwd")
        reused = Path(cwd) / reused if cwd else reused
    return reused

def kept_iteration(job: Path, model: str) -> int | None:
    """The training iteration ``model.pt`` keeps (``models/<model>/selection.json``,
    ``select: best_validation``), or None when the job's models have no such file."""
    path = job_models_dir(job) / model / "selection.json"
    if not path.is_file():
        return None
    iteration = json.loads(path.read_text()).get("iteration")
    return None if iteration is None else int(iteration)

def training_processor(job: Path, model: str) -> str | None:
    """The processor that trained the job's ``model`` (``kernels.cpu`` of its ``model.pt``, own
    or reused; in a report's copy of the job, :data:`PROCESSOR_RECORD` beside it), or None when
    there is no such file or record. Trained weights differ across processor families
    (``docs/reliability.md``)."""
    folder = job_models_dir(job) / model
    if (folder / PROCESSOR_RECORD).is_file():
        return json.loads((folder / PROCESSOR_RECORD).read_text()).get("cpu")
    if not (folder / "model.pt").is_file():
        return None
    import torch

    record = torch.load(folder / "model.pt", map_location="cpu",
                        weights_only=True).get("kernels") or {}
    return record.get("cpu")

def collect_validation(sweep_dir: str | Path, *, method: str) -> pd.DataFrame:
    """One row per job: its overrides and ``method``'s validation scores under the protocol
    ``select_protocol`` chose (``data/protocol/<method>.json``): ``val_recall_at_100p``,
    ``val_auc_pr``, ``protocol``, ``finished`` (whether the job also evaluated the test routes),
    ``iterations`` (trained) and ``kept_iteration`` (the one ``model.pt`` keeps).

    A job stopped after its ``select_protocol`` step counts here: the validation score needs
    nothing later."""
    rows = []
    for job, overrides in jobs_and_overrides(Path(sweep_dir), finished=False):
        path = job / "data" / "protocol" / f"{method}.json"
        if not path.is_file():
            continue
        record = json.loads(path.read_text())
        chosen = next((c for c in record.get("candidates", [])
                       if c["label"] == record["selected"]["label"]), {})
        rows.append({"job": job.name, **overrides, "method": method,
                     "finished": evaluated_test_routes(job),
                     "iterations": job_setting(job, f"models.{method}.iterations"),
                     "kept_iteration": kept_iteration(job, method),
                     "protocol": record["selected"]["label"],
                     "val_recall_at_100p": chosen.get("mean_recall_at_100p", np.nan),
                     "val_auc_pr": chosen.get("mean_auc_pr", np.nan)})
    return pd.DataFrame(rows)

def collect_invariance(sweep_dir: str | Path) -> pd.DataFrame:
    """One row per job, route and method of ``data/evaluation/invariance.json``."""
    rows = []
    for job, overrides in jobs_and_overrides(Path(sweep_dir)):
        path = job / "data" / "evaluation" / "invariance.json"
        if not path.is_file():
            continue
        for route, per_method in json.loads(path.read_text()).items():
            for method, stats_ in per_method.items():
                rows.append({"job": job.name, **overrides, "route": route, "method": method,
                             **{k: v for k, v in stats_.items()
                                if isinstance(v, (int, float))}})
    return pd.DataFrame(rows)

#: The files of a job that the seed report reads (beside the trained weights), copied under
#: ``jobs/<sweep name>/<job>/`` so that the numbers travel with their inputs and configs.
JOB_RECORDS = (".hydra/overrides.yaml", ".hydra/config.yaml", "metrics.json",
               "data/protocol/*.json", "data/evaluation/invariance.json",
               "data/features/*/info.json", "models/*/selection.json", "models/*/train_log.csv")
#: Written into a report's copy of a job for each trained model, in place of its ``model.pt``:
#: ``{"cpu": ...}``, the processor that trained it (:func:`training_processor`).
PROCESSOR_RECORD = "processor.json"

def copy_job_records(sweeps: dict[str, str | Path], out_dir: Path) -> list[Path]:
    """Copy each job's :data:`JOB_RECORDS` to ``out_dir/jobs/<sweep name>/<job>/`` (the same
    layout, so ``cmal-lcd seeds-report NAME=out_dir/jobs/NAME`` reads them again and writes the
    same report), and each trained model's :data:`PROCESSOR_RECORD` in place of its weights.
    Returns the copied files.

    How a job was run is left out, since it names folders of the machine that ran it: the
    plumbing overrides (:func:`is_plumbing_override`: ``app.*``, ``hydra.*``, ``methods``) and
    the ``app`` node of its config (which ``params.yaml`` never has either)."""
    copied = []
    for name, sweep in sweeps.items():
        for job in sweep_jobs(Path(sweep)):
            for pattern in JOB_RECORDS:
                for source in sorted(job.glob(pattern)):
                    target = out_dir / "jobs" / name / job.name / source.relative_to(job)
                    target.parent.mkdir(parents=True, exist_ok=True)
                    _copy_record(source, target)
                    copied.append(target)
            for model in _trained_models(job):
                target = out_dir / "jobs" / name / job.name / "models" / model / PROCESSOR_RECORD
                target.parent.mkdir(parents=True, exist_ok=True)
                target.write_text(json.dumps({"cpu": training_processor(job, model)}) + "\n")
                copied.append(target)
    return copied


def _trained_models(job: Path) -> list[str]:
    """The models the job used (its own or reused; a ``model.pt`` or, in a report's copy, a
    :data:`PROCESSOR_RECORD`), by name."""
    folder = job_models_dir(job)
    return sorted({path.parent.name for pattern in ("*/model.pt", f"*/{PROCESSOR_RECORD}")
                   for path in folder.glob(pattern)})

def _copy_record(source: Path, target: Path) -> None:
    """Copy one job record; a Hydra overrides or config file without the run's plumbing."""
    import shutil

    if source.parent.name != ".hydra":
        shutil.copyfile(source, target)
        return
    data = yaml.safe_load(source.read_text())
    if source.name == "overrides.yaml":
        data = [o for o in data or [] if not is_plumbing_override(str(o).partition("=")[0])]
    elif isinstance(data, dict):
        data.pop("app", None)
    target.write_text(yaml.safe_dump(data, sort_keys=False))

def method_labels(sweeps: dict[str, str | Path]) -> dict[str, dict[str, list[str]]]:
    """``{method: {row label: [sweep names]}}`` from the jobs' ``data/features/<method>/info.json``
    (the first job of each sweep that has one; a trained model labels its own codes with its
    objective, so one method key can be two rows when the sweeps differ in objective)."""
    labels: dict[str, dict[str, list[str]]] = {}
    for name, sweep in sweeps.items():
        seen: set[str] = set()
        for job in sweep_jobs(Path(sweep)):
            for info in sorted(job.glob("data/features/*/info.json")):
                label = json.loads(info.read_text()).get("label")
                if label and info.parent.name not in seen:
                    seen.add(info.parent.name)
                    labels.setdefault(info.parent.name, {}).setdefault(str(label), []).append(name)
    return labels
