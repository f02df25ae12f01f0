"""Table III figures: per-frame inference time and bytes per frame of every feature method.

Times raw uint8 frame -> code (resize, normalisation, network or SAD thumbnail) at batch 1 and
batched, median over repeats after warm-up, with :func:`cmal_lcd.features.timing.time_per_frame`.
Learned methods use ``models/<name>/model.pt`` when it exists, else the same network with its
seeded random initialisation (inference cost does not depend on the weights' values).

    /work/venv/bin/python benchmarks/bench_features.py [--frames 64] [--batch-size 32] \\
        [--repeats 20] [--warmup 3] [--threads 1] [--height 128] [--width 256] \\
        [--dnn-batches 1 2 4 8 16 32] [--dnn-at block10@224 block4@64]

``--dnn-batches`` also prints the DNN's per-frame time at each batch size (one call on that many
frames, divided by it): the figures behind ``features.dnn.batch_size``. ``--dnn-at`` times the
``dnn`` method at each ``LAYER@SIDE`` (an EfficientNet-Lite0 block at an input side, as the
features stage's validation choice may pick: ``features.dnn.image_size_candidates``).
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

import numpy as np
import torch
from omegaconf import OmegaConf

from cmal_lcd.config import CONF_DIR, REPO_ROOT
from cmal_lcd.features import build_extractor, extractor_conf
from cmal_lcd.features.learned import learned_extractor
from cmal_lcd.features.timing import time_per_frame

CONDITIONS = ("sunny", "rainy", "foggy")


def bench_config() -> OmegaConf:
    conf = Path(CONF_DIR)
    return OmegaConf.create({
        "seed": 0,
        "features": OmegaConf.load(conf / "features" / "default.yaml"),
        "matching": OmegaConf.load(conf / "matching" / "seqslam.yaml"),
        "models": {name: OmegaConf.load(conf / "model" / f"{name}.yaml")
                   for name in ("cmal", "bigan")},
    })


def extractors(cfg, models_dir: Path, *, batch_size: int):
    """(name, extractor or None, note) for every method, in table order."""
    from cmal_lcd.models import build_model

    cfg.features.batch_size = batch_size
    meta = {"conditions": list(CONDITIONS), "image_size": [128, 256]}
    for name in ("sad", "dnn"):
        try:
            yield name, build_extractor(name, conf=extractor_conf(cfg, name)), ""
        except (ImportError, ValueError) as exc:
            yield name, None, f"unavailable: {exc}"
    for name in ("bigan", "cmal"):
        if (models_dir / name / "model.pt").is_file():
            yield name, build_extractor(name, conf=extractor_conf(cfg, name),
                                        model_dir=models_dir), ""
            continue
        model_cfg = OmegaConf.to_container(cfg.models[name])
        model = build_model(name, model_cfg, image_size=int(model_cfg["image_size"]),
                            n_conditions=len(CONDITIONS), seed=0)
        yield name, learned_extractor(name, model, image_size=int(model_cfg["image_size"]),
                                      weights="random init", batch_size=batch_size,
                                      device=torch.device("cpu")), "untrained weights (no model.pt)"
    yield ("cmal_untrained",
           build_extractor("cmal_untrained",
                           conf=extractor_conf(cfg, "cmal_untrained", dataset_meta=meta)), "")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=64)
    parser.add_argument("--batch-size", type=int, default=32)
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--warmup", type=int, default=3)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--height", type=int, default=128)
    parser.add_argument("--width", type=int, default=256)
    parser.add_argument("--models", type=Path, default=REPO_ROOT / "models")
    parser.add_argument("--dnn-batches", type=int, nargs="*", default=[],
                        help="also time dnn and dnn_head at these batch sizes")
    parser.add_argument("--dnn-at", nargs="*", default=[], metavar="LAYER@SIDE",
                        help="also time dnn at these blocks and input sides, e.g. block4@64")
    args = parser.parse_args()
    logging.basicConfig(level=logging.ERROR)
    torch.set_num_threads(args.threads)

    frames = np.random.default_rng(0).integers(0, 256, (args.frames, args.height, args.width, 3),
                                               dtype=np.uint8)
    print(f"frames {args.frames} x {args.height}x{args.width} RGB uint8; batch {args.batch_size}; "
          f"median of {args.repeats} after {args.warmup} warm-up; torch threads {args.threads}")
    header = (f"{'method':<15} {'label':<26} {'dim':>5} {'bytes/frame':>11} {'batch1 ms':>10} "
              f"{'batched ms':>10}  note")
    print(header)
    print("-" * len(header))
    devices: list[str] = []
    for name, extractor, note in extractors(bench_config(), args.models,
                                            batch_size=args.batch_size):
        if extractor is None:
            print(f"{name:<15} {'-':<26} {'':>5} {'':>11} {'':>10} {'':>10}  {note}")
            continue
        codes = extractor(frames[:2])
        t = time_per_frame(extractor, frames, batch_size=args.batch_size, repeats=args.repeats,
                           warmup=args.warmup)
        if t["device"] not in devices:
            devices.append(t["device"])
        bytes_per_frame = codes.shape[1] * codes.dtype.itemsize
        print(f"{name:<15} {extractor.label:<26} {codes.shape[1]:>5} {bytes_per_frame:>11} "
              f"{t['batch1_ms']:>10.2f} {t['batched_ms']:>10.2f}  {note}")
    for device in devices:
        print(f"device: {device}")
    if args.dnn_batches:
        dnn_batch_sweep(bench_config(), frames, args.dnn_batches, repeats=args.repeats,
                        warmup=args.warmup)
    if args.dnn_at:
        dnn_layer_sweep(bench_config(), frames, args.dnn_at, repeats=args.repeats,
                        warmup=args.warmup)


def dnn_layer_sweep(cfg, frames: np.ndarray, pairs: list[str], *, repeats: int,
                    warmup: int) -> None:
    """Per-frame ms of ``dnn`` at each ``LAYER@SIDE``, at batch 1 and at
    ``features.dnn.batch_size``."""
    batch = int(cfg.features.dnn.batch_size)
    print(f"\ndnn by layer and input side (ms per frame; batched = batch {batch})")
    print(f"{'layer':<9} {'side':>5} {'dim':>5} {'batch1 ms':>10} {'batched ms':>10}")
    for pair in pairs:
        layer, _, side = pair.partition("@")
        cfg.features.dnn.efficientnet_layer = layer
        cfg.features.dnn.image_size = int(side)
        extractor = build_extractor("dnn", conf=extractor_conf(cfg, "dnn"))
        t = time_per_frame(extractor, frames, batch_size=batch, repeats=repeats, warmup=warmup)
        print(f"{layer:<9} {int(side):>5} {extractor(frames[:1]).shape[1]:>5} "
              f"{t['batch1_ms']:>10.2f} {t['batched_ms']:>10.2f}")


def dnn_batch_sweep(cfg, frames: np.ndarray, batches: list[int], *, repeats: int,
                    warmup: int) -> None:
    """Per-frame ms of ``dnn`` (its configured layer) and ``dnn_head`` at each batch size."""
    layer = cfg.features.dnn.efficientnet_layer
    print(f"\nDNN per-frame time by batch size (ms per frame; dnn at layer {layer}; one call on "
          f"`batch` frames, divided by batch)")
    print(f"{'method':<10}" + "".join(f"{b:>9}" for b in batches))
    for name in ("dnn", "dnn_head"):
        row = []
        for batch in batches:
            cfg.features.dnn.batch_size = batch
            try:
                extractor = build_extractor(name, conf=extractor_conf(cfg, name))
            except (ImportError, ValueError) as exc:
                print(f"{name:<10} unavailable: {exc}")
                break
            t = time_per_frame(extractor, frames, batch_size=batch, repeats=repeats,
                               warmup=warmup)
            row.append(t["batched_ms"])
        else:
            print(f"{name:<10}" + "".join(f"{ms:>9.2f}" for ms in row))


if __name__ == "__main__":
    main()
