"""Stage ``train@<model>``: train a model (CMAL, BiGAN, ...) on the dataset's training split.

Reads ``data/dataset`` (training frames and their weather labels; the validation drives, scored
every ``validate_every`` iterations, see :mod:`cmal_lcd.evaluation.monitor`) and the
``models.<model>`` node of the config; writes ``models/<model>/`` (``model.pt``, ``train_log.csv``,
``samples/``) and keeps the resume state in the checkpoints folder (declared
``persist: true``, so a killed ``dvc repro`` resumes). Paper Fig. 11 (CMAL's reconstructions
of the frames held out here) is computed by the report stage from ``model.pt``
(:mod:`cmal_lcd.reports.reconstructions`)::

    python -m cmal_lcd.stages.train --model cmal [--params params.yaml]
        [--dataset data/dataset] [--out models/cmal] [--checkpoints checkpoints/cmal]
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from cmal_lcd.evaluation.monitor import dataset_monitor
from cmal_lcd.models import MODEL_NAMES, train_model
from cmal_lcd.stages import parse_stage_args, run, stage_config, stage_item, stage_parser
from cmal_lcd.paths import REPO

# named, not __name__: that is "__main__" under `python -m` (how dvc.yaml runs it)
logger = logging.getLogger("cmal_lcd.stages.train")

#: Read, but not inputs: the monitor reads the whole search, then MONITOR_PROTOCOL replaces these.
NOT_INPUTS = {"matching.r_window": "replaced by MONITOR_PROTOCOL",
              "matching.enhance": "replaced by MONITOR_PROTOCOL"}


def condition_labels(conditions_of_frames, conditions) -> np.ndarray:
    """Label of each frame: the position of its condition name in ``conditions``.

    Raises
    ------
    ValueError
        Naming the first condition not in ``conditions``.
    """
    index = {name: i for i, name in enumerate(conditions)}
    unknown = sorted(set(conditions_of_frames) - set(index))
    if unknown:
        raise ValueError(f"condition: {unknown} not in dataset.json conditions {list(conditions)}")
    return np.asarray([index[c] for c in conditions_of_frames], dtype=np.int64)


def main(cfg, *, model_name: str, dataset_dir: str | Path, out_dir: str | Path,
         checkpoints_dir: str | Path | None = None, device: str | None = None) -> Path:
    """Train ``model_name`` on ``dataset_dir``'s training split; return ``model.pt``'s path.

    Parameters
    ----------
    cfg : DictConfig
        The composed config (``models.<model_name>``, ``seed``, ``runtime.threads``).
    model_name : str
        One of :data:`cmal_lcd.models.MODEL_NAMES`.
    dataset_dir, out_dir : path
    checkpoints_dir : path, optional
        Resume state; default ``out_dir / "checkpoints"``.
    device : str, optional
        Default: CUDA when available, else CPU.
    """
    from cmal_lcd.data.store import load_dataset

    if model_name not in MODEL_NAMES:
        raise ValueError(f"model_name: expected one of {MODEL_NAMES}, got {model_name!r}")
    if model_name not in cfg.models:
        raise ValueError(f"model_name: no models.{model_name} node in the config")
    model_cfg = cfg.models[model_name]
    dataset = load_dataset(dataset_dir)
    images, frames = dataset.train()
    conditions = list(dataset.meta["conditions"])
    labels = condition_labels(frames["condition"].tolist(), conditions)
    out_dir = Path(out_dir)
    monitor = None
    if model_cfg.validate_every and dataset.pairs("val"):  # types: the schema's, at load
        monitor = dataset_monitor(dataset, cfg.matching,
                                  per_condition=cfg.features.train_frames_per_condition)
    return train_model(model_name, model_cfg, images, labels, conditions=conditions,
                       out_dir=out_dir, seed=cfg.seed, threads=cfg.runtime.threads,
                       device=device, checkpoint_dir=checkpoints_dir, monitor=monitor,
                       poses=frames[["x", "y", "heading"]].to_numpy(np.float64))


def cli(argv: list[str] | None = None) -> Path:
    """Command-line entry point (see the module docstring)."""
    parser = stage_parser(__doc__)
    parser.add_argument("--model", default=None,
                        help=f"one of {', '.join(MODEL_NAMES)} (default: the item of the DVC "
                             f"stage running it, $DVC_STAGE)")
    parser.add_argument("--dataset", default=REPO.dataset, type=Path)
    parser.add_argument("--out", default=None, type=Path, help=f"default: {REPO.models}/<model>")
    parser.add_argument("--checkpoints", default=None, type=Path,
                        help=f"resume state folder; default: {REPO.checkpoints('<model>')}")
    args = parse_stage_args(parser, argv)
    args.model = stage_item(args.model, stage="train", option="--model")
    if args.model not in MODEL_NAMES:
        raise ValueError(f"--model: {args.model!r} is not a model; expected one of "
                         f"{', '.join(MODEL_NAMES)}")
    cfg = stage_config(args, __name__, args.model)
    return main(cfg, model_name=args.model, dataset_dir=args.dataset,
                out_dir=args.out or args.paths.model(args.model),
                checkpoints_dir=args.checkpoints or args.paths.checkpoints(args.model))


if __name__ == "__main__":
    run(cli)
