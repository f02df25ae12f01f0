"""Shared fixtures for the feature-extractor tests: one torch thread, a few tiny frames."""

import numpy as np
import pytest
import torch

torch.set_num_threads(1)


@pytest.fixture
def frames() -> np.ndarray:
    """Six random RGB frames, uint8 (6, 48, 64, 3), fixed seed."""
    return np.random.default_rng(0).integers(0, 256, size=(6, 48, 64, 3), dtype=np.uint8)


@pytest.fixture
def no_vgg16_in_hub(tmp_path, monkeypatch):
    """Point ``$TORCH_HOME`` at an empty folder so no cached VGG16 is found."""
    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "torch_home"))
    return tmp_path / "torch_home"


@pytest.fixture
def vgg16_state_file(tmp_path):
    """Factory: a VGG16 state dict file whose tensors are one constant (expanded scalars, tiny).

    ``vgg16_state_file(value=0.0, drop=())`` -> path; the keys are those of the module's own
    ``state_dict()`` (tests/features/test_vgg16.py checks they are torchvision's).
    """
    from cmal_lcd.features.vgg16 import VGG16

    def make(*, value: float = 0.0, drop=(), name: str = "vgg16-397923af.pth"):
        with torch.device("meta"):
            shapes = {k: v.shape for k, v in VGG16().state_dict().items()}
        state = {k: torch.full((), value).expand(s) for k, s in shapes.items() if k not in drop}
        path = tmp_path / name
        torch.save(state, path)
        return path

    return make
