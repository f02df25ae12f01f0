"""Helpers for tests of validation scoring: two drives of the same places, a pixel encoder."""

import sys
from pathlib import Path

import numpy as np
import pandas as pd
import torch

from cmal_lcd.evaluation.monitor import ValidationMonitor
from cmal_lcd.matching import SeqSLAMParams

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "models"))
from model_helpers import CONDITIONS, weather_frames  # noqa: E402


class FlattenEncoder(torch.nn.Module):
    """``encode(x)``: the frame's pixels (place-specific for distinct frames)."""

    def __init__(self, *, scale: float = 1.0):
        super().__init__()
        self.scale = torch.nn.Parameter(torch.tensor(scale), requires_grad=False)
        self.image_size = 16

    def encode(self, x):
        return self.scale * x.flatten(1)


def validation_drives(n=40, *, seed=0):
    """Two drives of the same ``n`` places (same index = same place), the second tinted."""
    rng = np.random.default_rng(seed)
    places = rng.integers(0, 200, (n, 16, 16, 3))
    images = np.concatenate([places, places + 40]).clip(0, 255).astype(np.uint8)
    frames = pd.DataFrame({"drive": ["val/a"] * n + ["val/b"] * n})
    return images, frames, [["val", "val/a", "val/b", "a-b"]]


def monitor_for(images, frames, pairs, **kw):
    centring, labels = weather_frames(30)
    return ValidationMonitor(
        val_images=images, val_frames=frames, pairs=pairs, centring_images=centring,
        centring_labels=labels, n_conditions=len(CONDITIONS),
        params=SeqSLAMParams.defaults(ds=4, v_min=1.0, v_max=1.0, v_step=0.1), d_thresh=1,
        ground_truth="index", pose_tolerance=5.0, batch_size=16, **kw)
