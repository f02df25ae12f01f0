"""Shared fixtures for the model tests: one torch thread, tiny frames."""

from __future__ import annotations

import pytest
import torch
from model_helpers import weather_frames

torch.set_num_threads(1)


@pytest.fixture
def frames_and_labels():
    """24 random 16x16 frames tinted by their weather label (0, 1, 2 in turn)."""
    return weather_frames()


@pytest.fixture(params=["cmal", "bigan"])
def model_name(request) -> str:
    return request.param
