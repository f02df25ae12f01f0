"""Fixtures of the weather-world tests: the real composed config, shrunk to a tiny world."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from omegaconf import DictConfig, OmegaConf

TINY_WORLD = Path(__file__).with_name("tiny_world.yaml")


def tiny_cfg(overrides: tuple[str, ...] = ()) -> DictConfig:
    """``compose(overrides)`` with the ``data`` node shrunk by ``tiny_world.yaml``."""
    from cmal_lcd.config import compose

    cfg = compose(list(overrides))
    data = OmegaConf.to_container(cfg.data, resolve=True)
    for key, value in yaml.safe_load(TINY_WORLD.read_text()).items():
        if isinstance(value, dict):
            data[key].update(value)
        else:
            data[key] = value
    plain = OmegaConf.to_container(cfg, resolve=True)
    plain["data"] = data
    return OmegaConf.create(plain)


@pytest.fixture(scope="session")
def tiny():
    """``(cfg, config, world)`` of the tiny world, seed 0 (built once per session)."""
    from cmal_lcd.data.world import DataConfig, build_world

    cfg = tiny_cfg()
    config = DataConfig.from_config(cfg.data)
    return cfg, config, build_world(config, seed=0)
