"""Helpers shared by the model tests: tiny configs and tiny labelled frames."""

from __future__ import annotations

import numpy as np
from omegaconf import OmegaConf

from cmal_lcd.config import CONF_DIR

CONDITIONS = ["sunny", "foggy", "rainy"]


def tiny_config(name: str, **overrides) -> dict:
    """``conf/model/<name>.yaml`` shrunk to 16x16 frames, width 4, a few iterations; CMAL's
    with the paper's objective (``conf/objective/paper.yaml``: no eq. 7 prior, no eq. 8
    adversary)."""
    cfg = OmegaConf.to_container(OmegaConf.load(CONF_DIR / "model" / f"{name}.yaml"))
    if name == "cmal":
        paper = OmegaConf.to_container(OmegaConf.load(CONF_DIR / "objective" / "paper.yaml"))
        cfg["loss_weights"] = {**cfg["loss_weights"], **paper}
    cfg.update(image_size=16, width=4, iterations=4, batch_size=8, checkpoint_every=2,
               log_every=2, sample_every=2, sample_count=4, heldout_fraction=0.25)
    if name == "cmal":
        cfg["classifier_width"] = 4
    if name == "bigan":
        cfg["discriminator_hidden"] = 16
    for key, value in overrides.items():
        if isinstance(value, dict):
            cfg[key] = {**cfg[key], **value}
        else:
            cfg[key] = value
    return cfg


def weather_frames(n: int = 24, *, size: int = 16, seed: int = 0):
    """Random frames whose weather label shifts their colour (a learnable cue).

    Returns
    -------
    images : uint8 (n, size, size, 3); labels : int64 (n,), cycling 0, 1, 2.
    """
    rng = np.random.default_rng(seed)
    labels = np.arange(n) % len(CONDITIONS)
    base = rng.integers(0, 156, (n, size, size, 3))
    tint = np.array([[80, 40, 0], [60, 60, 60], [0, 20, 90]])[labels][:, None, None, :]
    return (base + tint).clip(0, 255).astype(np.uint8), labels.astype(np.int64)


def write_model_file(models_dir, name: str, *, conditions, image_size: int = 16,
                     seed: int = 0):
    """``<models_dir>/<name>/model.pt`` in the train stage's format, holding the seeded,
    untrained :func:`tiny_config` network; returns the model (eval mode)."""
    import torch

    from cmal_lcd.models import build_model

    cfg = tiny_config(name, image_size=image_size)
    model = build_model(name, cfg, image_size=image_size, n_conditions=len(conditions),
                        seed=seed)
    (models_dir / name).mkdir(parents=True, exist_ok=True)
    torch.save({"name": name, "config": cfg, "conditions": list(conditions),
                "image_size": image_size, "state_dict": model.state_dict(), "iteration": 0},
               models_dir / name / "model.pt")
    return model.eval()
