"""The whole chain as one Hydra app: ``cmal-lcd-run [overrides]`` or ``cmal-lcd-run -m ...``.

Runs the same stage functions as ``dvc repro`` (``cmal_lcd.stages.*.main``) on one composed
config (``conf/app.yaml`` = ``conf/config.yaml`` + an ``app`` node), writing everything into
the Hydra job folder (``outputs/...`` or ``multirun/...``, both git- and dvc-ignored), never
into the repository's tracked paths. The job folder gets:

- ``data/dataset``, ``models/<name>``, ``data/features/<method>``, ``data/protocol/<method>.json``,
  ``data/evaluation/<method>``, ``data/evaluation/invariance.json``
- ``reports/`` (tables, figures, ``metrics.json``) as in the DVC pipeline (step ``report``)
- ``metrics.json``: the job's flat summary ``{"route/pair/method/metric": value}`` of the
  ``selected`` variant (each method's protocol chosen on the validation drives), collected
  by ``cmal-lcd aggregate``.

Which learned models a job trains follows ``methods``: ``methods=[sad,cmal],[sad,bigan]``
sweeps the learned model (``model`` itself is a config group used twice, for ``models.cmal``
and ``models.bigan``, so ``model=cmal,bigan`` does not select anything).

Launchers are Hydra config: ``hydra/launcher=joblib`` (local, parallel) or
``hydra/launcher=submitit_slurm`` (a SLURM cluster), ``submitit_local`` (here, for testing).
See docs/sweeps.md.

The app composes ``conf/`` of the checkout it is run in (:func:`cmal_lcd.config.checkout_root`:
``$CMAL_LCD_REPO``, else the nearest folder at or above the working directory holding
``conf/config.yaml``), never the one the package was installed from. Names are checked before
any step runs (:func:`cmal_lcd.config.check_config`); a failure is one line and exit code 2
(``CMAL_LCD_TRACEBACK=1`` or ``HYDRA_FULL_ERROR=1`` adds the traceback).
"""

from __future__ import annotations

import json
import logging
import os
import sys
from pathlib import Path
from typing import Mapping

import hydra
from omegaconf import DictConfig

from cmal_lcd.config import check_config
from cmal_lcd.io import atomic_write_json

logger = logging.getLogger(__name__)

#: Steps of the chain, in the order they run (the DVC stages, minus ``calibrate_world``).
STEPS = ("dataset", "train", "extract_features", "select_protocol", "evaluate", "analyse_codes",
         "report")
#: Learned methods whose features read a trained model ``models/<name>/``.
LEARNED_METHODS = ("cmal", "bigan")
#: The evaluation variant summarised in ``metrics.json`` (the protocol chosen on validation).
SUMMARY_VARIANT = "selected"


def resolve_reused(path: str | None, *, key: str) -> Path | None:
    """Absolute path of an ``app.reuse.<key>`` folder (relative to the launch directory).

    Raises
    ------
    FileNotFoundError
        When the folder does not exist (the message names ``app.reuse.<key>``).
    """
    if path is None:
        return None
    resolved = Path(hydra.utils.to_absolute_path(str(path)))
    if not resolved.exists():
        raise FileNotFoundError(f"app.reuse.{key}: {resolved} does not exist")
    return resolved


def models_to_train(methods, model_names) -> list[str]:
    """Names of ``model_names`` that some method of ``methods`` needs trained weights of.

    ``cmal_untrained`` needs no training; ``cmal`` and ``bigan`` need ``models/<name>``.
    """
    return [name for name in model_names if name in set(methods)]


def flat_summary(evaluations: Mapping[str, Mapping], *,
                 variant: str = SUMMARY_VARIANT) -> dict[str, float | None]:
    """Flatten per-method evaluation metrics into ``{"route/pair/method/metric": value}``.

    Parameters
    ----------
    evaluations : mapping
        ``{method: {route: {pair: {variant: {metric: value}}}}}`` (each method's
        ``data/evaluation/<method>/metrics.json``).
    variant : str
        Which variant to keep (``selected``: the protocol chosen on validation drives;
        ``paper``: the paper's protocol, an ablation).

    Raises
    ------
    ValueError
        When a method has no entry for ``variant``.
    """
    flat: dict[str, float | None] = {}
    for method, routes in evaluations.items():
        for route, pairs in routes.items():
            for pair, variants in pairs.items():
                if variant not in variants:
                    raise ValueError(f"variant: {method} {route} {pair} has no {variant!r} "
                                     f"entry (has {sorted(variants)})")
                for key, value in variants[variant].items():
                    flat[f"{route}/{pair}/{method}/{key}"] = value
    return dict(sorted(flat.items()))


def run_chain(cfg: DictConfig, job_dir: Path) -> dict[str, float | None]:
    """Run the configured steps of the pipeline in ``job_dir``; return the flat summary.

    ``app.reuse.{dataset,models,features}`` replace the job's own folder (and skip the step
    that makes it). The summary is also written to ``job_dir/metrics.json``.

    Raises
    ------
    ValueError
        When ``app.steps`` names an unknown step, or a name of the config is unsafe
        (:func:`cmal_lcd.config.check_config`).
    """
    check_config(cfg)
    from cmal_lcd.stages import (analyse_codes, evaluate, extract_features, make_dataset,
                                 report, select_protocol, train)

    steps = list(cfg.app.steps)
    unknown = sorted(set(steps) - set(STEPS))
    if unknown:
        raise ValueError(f"app.steps: unknown steps {unknown}; choose from {list(STEPS)}")
    reuse = cfg.app.reuse
    dataset_dir = resolve_reused(reuse.dataset, key="dataset") or job_dir / "data" / "dataset"
    models_dir = resolve_reused(reuse.models, key="models") or job_dir / "models"
    features_dir = (resolve_reused(reuse.features, key="features")
                    or job_dir / "data" / "features")
    evaluation_dir = job_dir / "data" / "evaluation"
    protocol_dir = job_dir / "data" / "protocol"
    methods = list(cfg.methods)
    logger.info("job %s: steps %s, methods %s", job_dir, steps, methods)

    if "dataset" in steps and reuse.dataset is None:
        make_dataset.main(cfg, out_dir=dataset_dir, manifest=dataset_dir.parent / "manifest.csv")
    if "train" in steps and reuse.models is None:
        for name in models_to_train(methods, cfg.model_names):
            train.main(cfg, model_name=name, dataset_dir=dataset_dir,
                       out_dir=models_dir / name,
                       checkpoints_dir=job_dir / "checkpoints" / name)
    if "extract_features" in steps and reuse.features is None:
        for method in methods:
            extract_features.main(cfg, method=method, dataset_dir=dataset_dir,
                                  models_dir=models_dir, out_dir=features_dir / method)
    if "select_protocol" in steps:
        for method in methods:
            select_protocol.main(cfg, method=method, dataset_dir=dataset_dir,
                                 features_dir=features_dir / method,
                                 out_path=protocol_dir / f"{method}.json")
    if "evaluate" in steps:
        for method in methods:
            evaluate.main(cfg, method=method, dataset_dir=dataset_dir,
                          features_dir=features_dir / method,
                          protocol_path=protocol_dir / f"{method}.json",
                          out_dir=evaluation_dir / method)
    if "analyse_codes" in steps:
        analyse_codes.main(cfg, dataset_dir=dataset_dir, features_dir=features_dir,
                           protocol_dir=protocol_dir, models_dir=models_dir,
                           out_path=evaluation_dir / "invariance.json")
    if "report" in steps:
        report.main(cfg, evaluation_dir=evaluation_dir, features_dir=features_dir,
                    protocol_dir=protocol_dir,
                    models_dir=models_dir, dataset_dir=dataset_dir,
                    out_dir=job_dir / "reports")
    evaluations = {m: json.loads(path.read_text()) for m in methods
                   if (path := evaluation_dir / m / "metrics.json").is_file()}
    summary = flat_summary(evaluations)
    atomic_write_json(job_dir / "metrics.json", summary)
    return summary


def objective(summary: Mapping[str, float | None]) -> float | None:
    """Mean recall at 100% precision of the learned methods (a sweeper objective), or None."""
    values = [v for k, v in summary.items()
              if k.endswith("/recall_at_100p") and k.split("/")[2] in LEARNED_METHODS
              and v is not None]
    return float(sum(values) / len(values)) if values else None


def run_job(cfg: DictConfig) -> float | None:
    """One Hydra job: :func:`run_chain` in the job folder; returns :func:`objective`.

    A failure ends the process with one line naming the file or key and exit code 2.
    """
    from hydra.core.hydra_config import HydraConfig

    from cmal_lcd.errors import report_failure

    job_dir = Path(HydraConfig.get().runtime.output_dir)
    try:
        return objective(run_chain(cfg, job_dir))
    except Exception as exc:  # noqa: BLE001 - the user-facing boundary
        verbose = any(os.environ.get(k, "") not in ("", "0")
                      for k in ("CMAL_LCD_TRACEBACK", "HYDRA_FULL_ERROR"))
        sys.exit(report_failure("cmal-lcd-run", exc, verbose=verbose))


def main() -> float | None:
    """``cmal-lcd-run``: Hydra on ``conf/`` of the checkout it is run in (see the module doc)."""
    from cmal_lcd.config import CheckoutNotFoundError, checkout_root
    from cmal_lcd.errors import report_failure

    try:
        conf_dir = checkout_root() / "conf"
    except CheckoutNotFoundError as exc:
        sys.exit(report_failure("cmal-lcd-run", exc))
    hydra_main = hydra.main(config_path=str(conf_dir), config_name="app", version_base="1.3")
    return hydra_main(run_job)()


if __name__ == "__main__":
    main()
