"""Stage ``extract_features@<method>``: codes of test, validation and sampled training frames.

Reads ``data/dataset`` (and ``models/<method>/model.pt`` for trained methods), writes under
``<out>``:

- ``codes.npy``: rows = test rows of ``frames.csv``, in file order;
- ``val_codes.npy``: rows = validation rows (``split == "val"``), in file order (may be empty);
- ``train_codes.npy`` + ``train_labels.npy``: ``features.train_frames_per_condition`` training
  frames per condition, evenly spaced (condition index per row), for the centring statistics
  of the matching protocol;
- ``info.json``: ``method, label, metric, dim, dtype, bytes_per_frame, weights, n_frames,
  n_val_frames, n_train_frames, layer_selection``;

and, apart from the codes, ``<timing>`` (default ``data/timing/<method>.json``): the Table III
per-frame inference time (``device, batch1_ms, batched_ms, batch_size, repeats, warmup,
n_frames``). Timings differ from run to run; kept out of ``<out>`` so that the codes folder,
which every later stage reads, has the same hash whenever the codes are the same (only the
report reads the timings).

Usage::

    python -m cmal_lcd.stages.extract_features --method dnn [--params params.yaml] \\
        [--dataset data/dataset] [--models models] [--out data/features/dnn] \\
        [--timing data/timing/dnn.json]
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from cmal_lcd.features import (check_finite_codes, configured_extractor, configured_method,
                               extractor_conf, located)
from cmal_lcd.features.base import encode_with_progress, forward_batch_size
from cmal_lcd.features.timing import time_per_frame
from cmal_lcd.io import atomic_save_npy, atomic_write_json
from cmal_lcd.matching.normalise import centring_sample
from cmal_lcd.stages import parse_stage_args, run, stage_config, stage_item, stage_parser
from cmal_lcd.paths import REPO

# named, not __name__: that is "__main__" under `python -m` (how dvc.yaml runs it)
logger = logging.getLogger("cmal_lcd.stages.extract_features")


#: Read, but not inputs: every method's conf gets a copy of the whole ``features`` node (its
#: keys are checked); only the dnn builders use ``features.dnn``, and they declare it.
NOT_INPUTS = {"features.dnn": "copied for the key check; used by dnn* only"}


def set_torch_threads(cfg: Mapping[str, Any]) -> None:
    """``torch.set_num_threads(cfg.runtime.threads)`` (checked by the schema when the config
    was loaded)."""
    import torch

    torch.set_num_threads(cfg["runtime"]["threads"])


def stored_codes(codes: np.ndarray) -> np.ndarray:
    """Codes as stored: uint8 kept, anything else float32."""
    return codes if codes.dtype in (np.uint8, np.float32) else codes.astype(np.float32)


def inference_timing(extractor, images: np.ndarray, conf: Mapping[str, Any], *,
                     method: str) -> dict[str, Any]:
    """Table III: per-frame inference time on the first ``features.timing.n_frames`` frames.

    Returns
    -------
    dict
        ``device, batch1_ms, batched_ms, batch_size, repeats, warmup, n_frames``; for
        precomputed codes (``extractor.lookup``) the device says so and the times are null.
    """
    if extractor.lookup is not None:
        return {"device": "precomputed (not timed)", "batch1_ms": None, "batched_ms": None,
                "batch_size": None, "repeats": 0, "warmup": 0, "n_frames": 0}
    timing_conf = conf["timing"]
    n_timing = max(1, min(int(timing_conf["n_frames"]), len(images)))
    timing = time_per_frame(extractor, np.ascontiguousarray(images[:n_timing]),
                            batch_size=forward_batch_size(extractor, conf),
                            repeats=int(timing_conf["repeats"]),
                            warmup=int(timing_conf["warmup"]))
    timing["n_frames"] = n_timing
    logger.info("%s: %.2f ms/frame at batch 1, %.2f ms/frame at batch %d (%s)", method,
                timing["batch1_ms"], timing["batched_ms"], timing["batch_size"], timing["device"])
    return timing


def _load_test_frames(dataset_dir: str | Path):
    """The dataset at ``dataset_dir`` and its test images ``uint8 (N, H, W, 3)``; ValueError
    when it has none."""
    from cmal_lcd.data.store import load_dataset

    dataset = load_dataset(dataset_dir)
    images, _ = dataset.test()
    if len(images) == 0:
        raise ValueError(f"dataset_dir: {dataset_dir} has no test frames")
    return dataset, images


def _configured_extractor(cfg: Mapping[str, Any], method: str, dataset, *,
                          models_dir: str | Path
                          ) -> tuple[Any, dict[str, Any], dict[str, Any] | None,
                                     dict[str, np.ndarray]]:
    """``method``'s extractor on the device training uses, its conf and, for a method that
    chooses on the validation drives (``Method.choose``: ``dnn``'s layer and input side), its
    choice and the chosen candidate's validation and centring codes (None and ``{}``
    otherwise)."""
    from cmal_lcd.models.device import pick_device

    device = pick_device()  # the rule training follows: CUDA when present, else CPU
    entry = configured_method(cfg, method)
    layer_selection, chosen_codes = (
        located(entry.choose)(cfg, extractor_conf(cfg, method, dataset_meta=dataset.meta),
                              dataset, device=device, method=method)
        if entry.choose is not None else (None, {}))
    extractor, conf = configured_extractor(cfg, method, model_dir=models_dir, device=device,
                                           choice=layer_selection, dataset_meta=dataset.meta)
    return extractor, conf, layer_selection, chosen_codes


def _write_codes(out_dir: Path, method: str, extractor, arrays: Mapping[str, np.ndarray], *,
                 layer_selection: dict[str, Any] | None) -> None:
    """``<name>.npy`` for each array of :func:`encode_dataset`, then ``info.json``
    (:func:`features_info`), into ``out_dir``."""
    for name, array in arrays.items():
        atomic_save_npy(out_dir / f"{name}.npy", array)
    atomic_write_json(out_dir / "info.json",
                      features_info(method, extractor, arrays, layer_selection=layer_selection))


def main(cfg: Mapping[str, Any], *, method: str, dataset_dir: str | Path = REPO.dataset,
         models_dir: str | Path = REPO.models, out_dir: str | Path | None = None,
         timing_path: str | Path | None = None) -> Path:
    """Extract and store the codes of all test frames with ``method``; returns ``out_dir``.

    Parameters
    ----------
    cfg : mapping
        The composed config (``params.yaml``): ``features``, ``runtime``, plus what the
        method needs (``matching.sad``, ``models.cmal``, ``seed``).
    method : str
        One of ``cmal_lcd.features.METHOD_NAMES``, or a node of ``cfg.extractors``.
    dataset_dir, models_dir : path
        The dataset written by ``make_dataset``; the folder holding ``<method>/model.pt``
        (trained methods only).
    out_dir : path, optional
        Default ``data/features/<method>``.
    timing_path : path, optional
        The Table III timing file (the command line's default: ``data/timing/<method>.json``);
        None: no timing is measured.

    Raises
    ------
    ValueError
        When the codes hold NaN or inf (naming the method and first bad frame; nothing written).
    """
    out_dir = Path(out_dir) if out_dir is not None else REPO.method_features(method)
    set_torch_threads(cfg)
    dataset, images = _load_test_frames(dataset_dir)
    extractor, conf, layer_selection, chosen_codes = _configured_extractor(
        cfg, method, dataset, models_dir=models_dir)
    arrays = encode_dataset(extractor, dataset, method=method,
                            batch_size=forward_batch_size(extractor, conf),
                            per_condition=int(conf["train_frames_per_condition"]),
                            known=chosen_codes)
    _write_codes(out_dir, method, extractor, arrays, layer_selection=layer_selection)
    if timing_path is not None:
        atomic_write_json(timing_path, inference_timing(extractor, images, conf, method=method))
    logger.info("%s: wrote %s codes %s to %s", method, arrays["codes"].dtype,
                arrays["codes"].shape, out_dir)
    return out_dir


def encode_dataset(extractor, dataset, *, method: str, batch_size: int, per_condition: int,
                   known: Mapping[str, np.ndarray] | None = None) -> dict[str, np.ndarray]:
    """Codes of the test frames, the validation frames and ``per_condition`` training frames
    per condition (the centring sample, :func:`~cmal_lcd.matching.normalise.centring_sample`).

    ``known`` may hold ``val_codes`` and ``train_codes`` the extractor's network already
    computed for these same frames (the DNN's layer choice): they are stored instead of
    encoding those frames again.

    Returns
    -------
    dict
        ``codes (N_test, F)``, ``val_codes (N_val, F)``, ``train_codes (N_train, F)`` (uint8 or
        float32, as stored) and ``train_labels int (N_train,)`` (condition index per row).

    Raises
    ------
    ValueError
        When codes hold NaN or inf (:func:`~cmal_lcd.features.check_finite_codes`).
    """
    if extractor.lookup is not None:
        return looked_up_dataset(extractor, dataset, method=method, per_condition=per_condition)
    images, _ = dataset.test()
    logger.info("%s (%s): encoding %d test frames; weights: %s", method, extractor.label,
                len(images), extractor.weights)

    known = known or {}

    def encode(frames: np.ndarray, what: str, name: str | None = None) -> np.ndarray:
        if name in known:
            if len(known[name]) != len(frames):
                raise ValueError(f"{method}: {len(known[name])} known {name} for "
                                 f"{len(frames)} {what}")
            raw = known[name]
        else:
            raw = encode_with_progress(extractor, frames, batch_size=batch_size,
                                       desc=f"{method}: encode {what}", logger=logger)
        return stored_codes(check_finite_codes(raw, method=method))

    codes = encode(images, "test frames")
    val_images, _ = dataset.validation()
    val_codes = (encode(val_images, "validation frames", "val_codes")
                 if len(val_images) else np.zeros((0, codes.shape[1]), codes.dtype))
    train_images, train_frames = dataset.train()
    rows, train_labels = centring_sample(dataset.conditions, train_frames["condition"],
                                         per_condition=per_condition)
    logger.info("%s: %s %d validation frames and %d training frames (centring statistics)",
                method, "codes of the layer choice for" if known else "encoding",
                len(val_images), len(rows))
    train_codes = (encode(train_images[rows], "training frames", "train_codes")
                   if len(rows) else np.zeros((0, codes.shape[1]), codes.dtype))
    return {"codes": codes, "val_codes": val_codes, "train_codes": train_codes,
            "train_labels": train_labels}


def looked_up_dataset(extractor, dataset, *, method: str, per_condition: int
                      ) -> dict[str, np.ndarray]:
    """:func:`encode_dataset`'s arrays for precomputed codes (``extractor.lookup``): the test,
    validation and centring-sample frames looked up by frame number; no training codes when
    some training frame has none (``LookupError``: the protocol then cannot centre by
    condition)."""
    sources = dataset.meta.get("sources") or []

    def look_up(frames) -> np.ndarray:
        codes = extractor.lookup(sources, frames["frame"].to_numpy())
        return stored_codes(check_finite_codes(np.asarray(codes), method=method))

    _, test_frames = dataset.test()
    codes = look_up(test_frames)
    logger.info("%s (%s): looked up %d test frames; %s", method, extractor.label,
                len(codes), extractor.weights)
    _, val_frames = dataset.validation()
    val_codes = look_up(val_frames) if len(val_frames) else np.zeros((0, codes.shape[1]),
                                                                       codes.dtype)
    _, train_frames = dataset.train()
    rows, train_labels = centring_sample(dataset.conditions, train_frames["condition"],
                                         per_condition=per_condition)
    try:
        train_codes = look_up(train_frames.iloc[rows]) if len(rows) else None
    except LookupError as missing:
        logger.warning("%s: no training codes (%s); the protocol cannot centre by condition",
                       method, missing)
        train_codes = None
    if train_codes is None:
        train_codes, train_labels = (np.zeros((0, codes.shape[1]), codes.dtype),
                                     np.zeros(0, dtype=np.asarray(train_labels).dtype))
    return {"codes": codes, "val_codes": val_codes, "train_codes": train_codes,
            "train_labels": train_labels}


def features_info(method: str, extractor, arrays: Mapping[str, np.ndarray], *,
                  layer_selection: dict[str, Any] | None) -> dict[str, Any]:
    """``info.json``: what the codes are (method, label, metric, shape, dtype, weights) and,
    for ``dnn`` and ``dnn_head``, the layer and side chosen on the validation drives."""
    codes = arrays["codes"]
    return {
        "method": method,
        "label": extractor.label,
        "metric": extractor.metric,
        "dim": int(codes.shape[1]),
        "dtype": str(codes.dtype),
        "bytes_per_frame": int(codes.shape[1] * codes.dtype.itemsize),
        "n_frames": int(codes.shape[0]),
        "n_val_frames": int(arrays["val_codes"].shape[0]),
        "n_train_frames": int(arrays["train_codes"].shape[0]),
        "weights": extractor.weights,
        "layer_selection": layer_selection,
    }


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    """Command-line options of ``python -m cmal_lcd.stages.extract_features``."""
    parser = stage_parser(__doc__)
    parser.add_argument("--method", default=None,
                        help="a built-in method or a node of `extractors` in --params "
                             "(default: the item of the DVC stage running it, $DVC_STAGE)")
    parser.add_argument("--dataset", default=REPO.dataset, type=Path, help="dataset folder")
    parser.add_argument("--models", default=REPO.models, type=Path, help="trained models folder")
    parser.add_argument("--out", default=None, type=Path,
                        help="output folder (default data/features/<method>)")
    parser.add_argument("--timing", default=None, type=Path,
                        help="Table III timing file (default data/timing/<method>.json)")
    return parse_stage_args(parser, argv)


def cli(argv: Sequence[str] | None = None) -> Path:
    """Entry point: load ``--params`` and run :func:`main`."""
    args = parse_args(argv)
    args.method = stage_item(args.method, stage="extract_features", option="--method")
    cfg = stage_config(args, __name__, args.method)
    timing = args.timing if args.timing is not None else args.paths.timing(args.method)
    out = args.out if args.out is not None else args.paths.method_features(args.method)
    return main(cfg, method=args.method, dataset_dir=args.dataset, models_dir=args.models,
                out_dir=out, timing_path=timing)


if __name__ == "__main__":
    run(cli)
