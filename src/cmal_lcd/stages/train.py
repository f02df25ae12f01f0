"""Stage ``train@<model>``: train CMAL or BiGAN on the dataset's training split.

Reads ``data/dataset`` (training frames and their weather labels; the validation drives, scored
every ``validate_every`` iterations, see :mod:`cmal_lcd.evaluation.monitor`) and the
``models.<model>`` node of the config; writes ``models/<model>/`` (``model.pt``, ``train_log.csv``,
``samples/``) and keeps the resume state in the checkpoints folder (declared
``persist: true``, so a killed ``dvc repro`` resumes). For CMAL it also writes
``models/cmal/reconstructions.npz`` (paper Fig. 11) from held-out frames::

    python -m cmal_lcd.stages.train --model cmal [--params params.yaml]
        [--dataset data/dataset] [--out models/cmal] [--checkpoints checkpoints/cmal]
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from cmal_lcd.evaluation.monitor import dataset_monitor
from cmal_lcd.io import atomic_save_npz
from cmal_lcd.models import MODEL_NAMES, heldout_split, load_trained, train_model
from cmal_lcd.models.cmal import nearest_view, reconstruct_and_translate, translation_pairs
from cmal_lcd.models.images import resize_images
from cmal_lcd.stages import run, stage_config, stage_parser

# named, not __name__: that is "__main__" under `python -m` (how dvc.yaml runs it)
logger = logging.getLogger("cmal_lcd.stages.train")

#: The config keys this stage reads for model ``{item}`` (its params in dvc.yaml; see
#: cmal_lcd.stages): the model's node, and the Table I search of the validation monitor.
PARAMS = ("seed", "runtime", "models.{item}", "matching.ds", "matching.v_min", "matching.v_max",
          "matching.v_step", "matching.score", "matching.d_thresh", "matching.pose_tolerance",
          "features.train_frames_per_condition")
#: Read, but not inputs: the monitor reads the whole search, then MONITOR_PROTOCOL replaces these.
NOT_INPUTS = {"matching.r_window": "replaced by MONITOR_PROTOCOL",
              "matching.enhance": "replaced by MONITOR_PROTOCOL"}

#: Examples in ``reconstructions.npz`` (rows of the Fig. 11 reproduction).
N_RECONSTRUCTIONS = 6


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


def write_reconstructions(model_dir: Path, images: np.ndarray, frames, labels: np.ndarray, *,
                          conditions, model_cfg: Mapping[str, Any], seed: int) -> Path:
    """Fig. 11 data from held-out frames: ``a, recon_a, translated_b, b`` and their conditions.

    ``b`` is the training frame of condition B nearest to frame ``a``'s pose (same place when
    the dataset revisits it), so a reader can compare the translation with a real view.
    """
    model, meta = load_trained(model_dir)
    _, heldout = heldout_split(len(images), fraction=float(model_cfg["heldout_fraction"]),
                               seed=seed)
    pool = heldout if len(heldout) else np.arange(len(images))
    positions, cond_a, cond_b = translation_pairs(labels[pool], n_conditions=len(conditions),
                                                  count=N_RECONSTRUCTIONS, seed=seed)
    rows_a = pool[positions]
    out = reconstruct_and_translate(model, images[rows_a], cond_a, cond_b)
    xy = frames[["x", "y"]].to_numpy(dtype=np.float64)
    heading = frames["heading"].to_numpy(dtype=np.float64)
    rows_b = []
    for row, b in zip(rows_a, cond_b):
        candidates = np.flatnonzero(labels == b)
        rows_b.append(int(candidates[nearest_view(xy[row], heading[row], xy[candidates],
                                                  heading[candidates])]))
    rows_b = np.asarray(rows_b, dtype=np.int64)
    names = np.asarray(list(conditions))
    frame_ids = frames["frame"].to_numpy() if "frame" in frames else frames.index.to_numpy()
    return atomic_save_npz(
        model_dir / "reconstructions.npz", a=out["a"], recon_a=out["recon_a"],
        translated_b=out["translated_b"],
        b=resize_images(images[rows_b], image_size=int(meta["image_size"])),
        condition_a=names[cond_a], condition_b=names[cond_b],
        frame_a=np.asarray(frame_ids[rows_a], dtype=np.int64),
        frame_b=np.asarray(frame_ids[rows_b], dtype=np.int64))


def main(cfg, *, model_name: str, dataset_dir: str | Path, out_dir: str | Path,
         checkpoints_dir: str | Path | None = None, device: str | None = None) -> Path:
    """Train ``model_name`` on ``dataset_dir``'s training split; return ``model.pt``'s path.

    Parameters
    ----------
    cfg : DictConfig
        The composed config (``models.<model_name>``, ``seed``, ``runtime.threads``).
    model_name : str
        ``cmal`` or ``bigan``.
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
    if model_cfg.get("validate_every", 0) and dataset.pairs("val"):
        monitor = dataset_monitor(dataset, cfg.matching,
                                  per_condition=int(cfg.features.train_frames_per_condition))
    path = train_model(model_name, model_cfg, images, labels, conditions=conditions,
                       out_dir=out_dir, seed=int(cfg.seed), threads=int(cfg.runtime.threads),
                       device=device, checkpoint_dir=checkpoints_dir, monitor=monitor)
    if model_name == "cmal" and len(conditions) >= 2:
        recon = write_reconstructions(out_dir, images, frames.reset_index(drop=True), labels,
                                      conditions=conditions, model_cfg=model_cfg,
                                      seed=int(cfg.seed))
        logger.info("wrote %s", recon)
    return path


def cli(argv: list[str] | None = None) -> Path:
    """Command-line entry point (see the module docstring)."""
    parser = stage_parser(__doc__)
    parser.add_argument("--model", required=True, choices=MODEL_NAMES)
    parser.add_argument("--dataset", default="data/dataset", type=Path)
    parser.add_argument("--out", default=None, type=Path, help="default: models/<model>")
    parser.add_argument("--checkpoints", default=None, type=Path,
                        help="resume state folder; default: <out>/checkpoints")
    args = parser.parse_args(argv)
    cfg = stage_config(args, __name__, args.model)
    return main(cfg, model_name=args.model, dataset_dir=args.dataset,
                out_dir=args.out or Path("models") / args.model, checkpoints_dir=args.checkpoints)


if __name__ == "__main__":
    run(cli)
