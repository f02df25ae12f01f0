"""The whole chain as one Hydra app: ``cmal-lcd-run [overrides]`` or ``cmal-lcd-run -m ...``.

Runs the same stage functions as ``dvc repro`` (``cmal_lcd.stages.*.main``) on one composed
config, writing everything into the Hydra job folder (``outputs/...`` or ``multirun/...``,
both git- and dvc-ignored), never into the repository's tracked paths. The job folder gets:

- ``data/dataset``, ``models/<name>``, ``data/features/<method>``, ``data/evaluation/<method>``
- ``reports/`` (tables, figures, ``metrics.json``) as in the DVC pipeline
- ``metrics.json``: the job's flat summary, collected by ``cmal-lcd aggregate``.

Launchers are Hydra config: ``hydra/launcher=joblib`` (local, parallel) or
``hydra/launcher=submitit_slurm`` (a SLURM cluster), ``submitit_local`` (here, for testing).
"""

from __future__ import annotations

import logging
from pathlib import Path

import hydra
from omegaconf import DictConfig

from cmal_lcd.config import CONF_DIR
from cmal_lcd.io import atomic_write_json

logger = logging.getLogger(__name__)

STEPS = ("dataset", "train", "extract_features", "evaluate", "report")
LEARNED_METHODS = {"cmal": "cmal", "bigan": "bigan"}


def _reused(path: str | None) -> Path | None:
    if path is None:
        return None
    resolved = Path(hydra.utils.to_absolute_path(path))
    if not resolved.exists():
        raise FileNotFoundError(f"app.reuse: {resolved} does not exist")
    return resolved


def flat_summary(metrics: dict) -> dict:
    """``{route: {pair: {method: {metric: v}}}}`` -> ``{"route/pair/method/metric": v}``."""
    flat = {}
    for route, pairs in metrics.items():
        for pair, methods in pairs.items():
            for method, values in methods.items():
                for key, value in values.items():
                    flat[f"{route}/{pair}/{method}/{key}"] = value
    return flat


def run_chain(cfg: DictConfig, job_dir: Path) -> dict:
    """Run the configured steps of the pipeline in ``job_dir``; return the report metrics."""
    from cmal_lcd.stages import evaluate, extract_features, make_dataset, report, train

    steps = list(cfg.app.steps)
    unknown = sorted(set(steps) - set(STEPS))
    if unknown:
        raise ValueError(f"app.steps: unknown steps {unknown}; choose from {list(STEPS)}")
    dataset_dir = _reused(cfg.app.reuse.dataset) or job_dir / "data" / "dataset"
    models_dir = _reused(cfg.app.reuse.models) or job_dir / "models"
    features_dir = _reused(cfg.app.reuse.features) or job_dir / "data" / "features"
    evaluation_dir = job_dir / "data" / "evaluation"
    reports_dir = job_dir / "reports"

    if "dataset" in steps and cfg.app.reuse.dataset is None:
        make_dataset.main(cfg, out_dir=dataset_dir)
    if "train" in steps and cfg.app.reuse.models is None:
        needed = [m for m in cfg.model_names
                  if any(method.startswith(m) for method in cfg.methods)]
        for name in needed:
            train.main(cfg, model_name=name, dataset_dir=dataset_dir,
                       out_dir=models_dir / name,
                       checkpoints_dir=job_dir / "checkpoints" / name)
    if "extract_features" in steps and cfg.app.reuse.features is None:
        for method in cfg.methods:
            extract_features.main(cfg, method=method, dataset_dir=dataset_dir,
                                  models_dir=models_dir, out_dir=features_dir / method)
    if "evaluate" in steps:
        for method in cfg.methods:
            evaluate.main(cfg, method=method, dataset_dir=dataset_dir,
                          features_dir=features_dir / method,
                          out_dir=evaluation_dir / method)
    metrics: dict = {}
    if "report" in steps:
        report.main(cfg, evaluation_dir=evaluation_dir, features_dir=features_dir,
                    models_dir=models_dir, dataset_dir=dataset_dir, out_dir=reports_dir)
        import json
        metrics = json.loads((reports_dir / "metrics.json").read_text())
    atomic_write_json(job_dir / "metrics.json", flat_summary(metrics))
    return metrics


@hydra.main(config_path=str(CONF_DIR), config_name="app", version_base="1.3")
def main(cfg: DictConfig) -> float | None:
    """Hydra entry point; returns the mean recall at 100% precision of the first learned
    method (a sweeper objective)."""
    from hydra.core.hydra_config import HydraConfig

    job_dir = Path(HydraConfig.get().runtime.output_dir)
    metrics = run_chain(cfg, job_dir)
    values = [v["recall_at_100p"] for pairs in metrics.values() for methods in pairs.values()
              for m, v in methods.items() if m in LEARNED_METHODS and v.get("recall_at_100p") is not None]
    return float(sum(values) / len(values)) if values else None


if __name__ == "__main__":
    main()
