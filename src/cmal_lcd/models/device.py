"""Where models run: CUDA when present, else CPU; never a config value.

A device in the config would have to come from the environment, and interpolating environment
values into ``params.yaml`` freezes them there (see docs/architecture.md); so code decides.
"""

from __future__ import annotations

import torch


def pick_device() -> str:
    """``"cuda"`` when a CUDA device is available, else ``"cpu"``."""
    return "cuda" if torch.cuda.is_available() else "cpu"
