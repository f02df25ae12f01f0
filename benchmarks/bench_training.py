"""Benchmark: seconds per training iteration and encoder inference time per frame.

Uses each model's node of the composed config (``models.<name>``: the default is 64x64,
width 16, batch 64; ``--overrides experiment=paper`` gives the paper's widths) on random frames,
so it needs no dataset. ``--device cuda`` times the GPU (synchronised before each clock read).
Prints one line per measurement::

    python benchmarks/bench_training.py [--models cmal bigan] [--threads 1 2] [--steps 10]
    python benchmarks/bench_training.py --device cuda --overrides experiment=paper --steps 50
    CMAL_LCD_NATIVE_KERNELS=1 python benchmarks/bench_training.py --precision float32 bfloat16

The figures depend on what else runs on the machine (torch with 2 threads is much slower when
another process is busy on a 2-core box); quote them with the machine's load.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np
import torch
from omegaconf import OmegaConf

from cmal_lcd.config import compose
from cmal_lcd.models import build_model, preprocess
from cmal_lcd.models.base import TrainingBatch
from cmal_lcd.models.training import seeded_noise, step_precision, torch_runtime


def random_batch(model, *, batch_size: int, n_conditions: int, seed: int,
                 device: str = "cpu") -> TrainingBatch:
    rng = np.random.default_rng(seed)
    frames = rng.integers(0, 256, (batch_size, model.image_size, model.image_size, 3), np.uint8)
    condition = rng.integers(0, n_conditions, batch_size)
    target = (condition + rng.integers(1, n_conditions, batch_size)) % n_conditions
    return TrainingBatch(x=preprocess(frames, image_size=model.image_size).to(device),
                         condition=torch.from_numpy(condition).to(device),
                         target=torch.from_numpy(target).to(device),
                         noise=seeded_noise(batch_size, model.code_dim, seed=seed).to(device))


def clock(device: str) -> float:
    """``time.perf_counter()`` after the device's queued work has finished."""
    if device == "cuda":
        torch.cuda.synchronize()
    return time.perf_counter()


def seconds_per_iteration(name: str, cfg: dict, *, threads: int, steps: int, device: str = "cpu",
                          warmup: int = 2) -> float:
    """Mean wall seconds of one ``training_step`` of model ``name`` (config node ``cfg``)."""
    with torch_runtime(threads=threads, deterministic=device == "cpu"):
        model = build_model(name, cfg, image_size=cfg["image_size"], n_conditions=3,
                            seed=0).to(device)
        opts = model.make_optimizers()
        batches = [random_batch(model, batch_size=cfg["batch_size"], n_conditions=3, seed=i,
                                device=device) for i in range(warmup + steps)]
        precision = cfg.get("precision", "float32")
        for b in batches[:warmup]:
            with step_precision(precision, device):
                model.training_step(b, opts)
        t0 = clock(device)
        for b in batches[warmup:]:
            with step_precision(precision, device):
                model.training_step(b, opts)
        return (clock(device) - t0) / steps


@torch.no_grad()
def encode_ms_per_frame(name: str, cfg: dict, *, threads: int, batch_size: int, frames: int,
                        device: str = "cpu") -> float:
    """Milliseconds per frame to encode random frames at ``batch_size``, preprocessing included."""
    with torch_runtime(threads=threads, deterministic=device == "cpu"):
        model = build_model(name, cfg, image_size=cfg["image_size"], n_conditions=3,
                            seed=0).to(device).eval()
        rng = np.random.default_rng(0)
        size = cfg["image_size"]
        images = rng.integers(0, 256, (frames, size, size, 3), np.uint8)
        model.encode(preprocess(images[:batch_size], image_size=size).to(device))
        t0 = clock(device)
        for start in range(0, frames, batch_size):
            model.encode(preprocess(images[start:start + batch_size], image_size=size).to(device))
        return (clock(device) - t0) / frames * 1e3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", nargs="+", default=["cmal", "bigan"])
    parser.add_argument("--threads", nargs="+", type=int, default=[1, 2])
    parser.add_argument("--steps", type=int, default=10)
    parser.add_argument("--device", choices=["cpu", "cuda"], default="cpu")
    parser.add_argument("--precision", nargs="+", choices=["float32", "bfloat16"], default=None,
                        help="training-step precisions to time (default: each model's config)")
    parser.add_argument("--overrides", nargs="*", default=[],
                        help="Hydra overrides for the model configs, e.g. experiment=paper")
    args = parser.parse_args()
    where = (torch.cuda.get_device_name() if args.device == "cuda"
             else f"{os.cpu_count()} CPUs")
    native = os.environ.get("CMAL_LCD_NATIVE_KERNELS", "0") not in ("", "0")
    print(f"torch {torch.__version__}, {where}, load average {os.getloadavg()[0]:.2f},"
          f" overrides {args.overrides or 'none'},"
          f" kernels {'native' if native else 'pinned (src/cmal_lcd/kernels.py)'}")
    composed = compose(args.overrides)
    for name in args.models:
        cfg = OmegaConf.to_container(composed.models[name])
        shape = (f"batch {cfg['batch_size']}, {cfg['image_size']}x{cfg['image_size']},"
                 f" width {cfg['width']}")
        for precision in args.precision or [cfg.get("precision", "float32")]:
            for threads in args.threads:
                s = seconds_per_iteration(name, {**cfg, "precision": precision},
                                          threads=threads, steps=args.steps, device=args.device)
                print(f"{name}: {s:.4f} s/iteration at {shape}, {args.device},"
                      f" {threads} thread(s), {precision}")
        for batch_size, frames in ((1, 200), (64, 1024)):
            ms = encode_ms_per_frame(name, cfg, threads=args.threads[0], batch_size=batch_size,
                                     frames=frames, device=args.device)
            print(f"{name}: encode {ms:.3f} ms/frame at batch {batch_size}, {args.device}")


if __name__ == "__main__":
    main()
