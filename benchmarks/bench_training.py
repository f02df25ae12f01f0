"""Benchmark: seconds per training iteration and encoder inference time per frame.

Uses the default ``conf/model/<name>.yaml`` (64x64, width 16, batch 64) on random frames, so
it needs no dataset. Prints one line per measurement::

    python benchmarks/bench_training.py [--models cmal bigan] [--threads 1 2] [--steps 10]

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

from cmal_lcd.config import CONF_DIR
from cmal_lcd.models import build_model, preprocess
from cmal_lcd.models.base import TrainingBatch
from cmal_lcd.models.training import seeded_noise, torch_runtime


def random_batch(model, *, batch_size: int, n_conditions: int, seed: int) -> TrainingBatch:
    rng = np.random.default_rng(seed)
    frames = rng.integers(0, 256, (batch_size, model.image_size, model.image_size, 3), np.uint8)
    condition = rng.integers(0, n_conditions, batch_size)
    target = (condition + rng.integers(1, n_conditions, batch_size)) % n_conditions
    return TrainingBatch(x=preprocess(frames, image_size=model.image_size),
                         condition=torch.from_numpy(condition), target=torch.from_numpy(target),
                         noise=seeded_noise(batch_size, model.code_dim, seed=seed))


def seconds_per_iteration(name: str, *, threads: int, steps: int, warmup: int = 2) -> float:
    cfg = OmegaConf.to_container(OmegaConf.load(CONF_DIR / "model" / f"{name}.yaml"))
    with torch_runtime(threads=threads, deterministic=True):
        model = build_model(name, cfg, image_size=cfg["image_size"], n_conditions=3, seed=0)
        opts = model.make_optimizers()
        batches = [random_batch(model, batch_size=cfg["batch_size"], n_conditions=3, seed=i)
                   for i in range(warmup + steps)]
        for b in batches[:warmup]:
            model.training_step(b, opts)
        t0 = time.perf_counter()
        for b in batches[warmup:]:
            model.training_step(b, opts)
        return (time.perf_counter() - t0) / steps


@torch.no_grad()
def encode_ms_per_frame(name: str, *, threads: int, batch_size: int, frames: int) -> float:
    cfg = OmegaConf.to_container(OmegaConf.load(CONF_DIR / "model" / f"{name}.yaml"))
    with torch_runtime(threads=threads, deterministic=True):
        model = build_model(name, cfg, image_size=cfg["image_size"], n_conditions=3,
                            seed=0).eval()
        rng = np.random.default_rng(0)
        images = rng.integers(0, 256, (frames, 64, 64, 3), np.uint8)
        model.encode(preprocess(images[:batch_size], image_size=model.image_size))
        t0 = time.perf_counter()
        for start in range(0, frames, batch_size):
            model.encode(preprocess(images[start:start + batch_size],
                                    image_size=model.image_size))
        return (time.perf_counter() - t0) / frames * 1e3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", nargs="+", default=["cmal", "bigan"])
    parser.add_argument("--threads", nargs="+", type=int, default=[1, 2])
    parser.add_argument("--steps", type=int, default=10)
    args = parser.parse_args()
    print(f"torch {torch.__version__}, {os.cpu_count()} CPUs, load average"
          f" {os.getloadavg()[0]:.2f}")
    for name in args.models:
        for threads in args.threads:
            s = seconds_per_iteration(name, threads=threads, steps=args.steps)
            print(f"{name}: {s:.3f} s/iteration at batch 64, 64x64, width 16,"
                  f" {threads} thread(s)")
        for batch_size, frames in ((1, 200), (64, 1024)):
            ms = encode_ms_per_frame(name, threads=1, batch_size=batch_size, frames=frames)
            print(f"{name}: encode {ms:.3f} ms/frame at batch {batch_size}, 1 thread")


if __name__ == "__main__":
    main()
