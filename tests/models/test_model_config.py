"""conf/model/*.yaml: composed under models.<name>, accepted by the loop and build_model."""

from collections.abc import Mapping

import pytest
import torch
from omegaconf import OmegaConf

from cmal_lcd.config import CONF_DIR, compose
from cmal_lcd.models import MODEL_NAMES, build_model
from cmal_lcd.models.config import model_config


def test_every_model_has_a_config_file():
    assert {p.stem for p in (CONF_DIR / "model").glob("*.yaml")} == set(MODEL_NAMES)


def default_objective() -> str | None:
    """The ``objective`` group chosen in ``conf/config.yaml`` (CMAL's loss-weight variants)."""
    for entry in OmegaConf.load(CONF_DIR / "config.yaml").defaults:
        if isinstance(entry, Mapping) and "objective" in entry:
            return entry["objective"]
    return None


def expected_node(name: str):
    """``conf/model/<name>.yaml``, with CMAL's loss weights completed by the default objective."""
    node = OmegaConf.load(CONF_DIR / "model" / f"{name}.yaml")
    objective = default_objective() if name == "cmal" else None
    if objective:
        weights = OmegaConf.load(CONF_DIR / "objective" / f"{objective}.yaml")
        node.loss_weights = OmegaConf.merge(node.loss_weights, weights)
    return node


@pytest.mark.parametrize("name", ["cmal", "bigan"])
def test_composed_config_has_a_trainable_node_per_model(name):
    cfg = compose([])
    node = cfg.models[name]
    assert node == expected_node(name)
    settings = model_config(name, node)
    assert settings.image_size == 64 and node.code_dim == 1024
    assert int(cfg.runtime.threads) >= 1
    model = build_model(name, node, image_size=settings.image_size,
                        n_conditions=3, seed=0)
    assert model.encode(torch.zeros(1, 3, 64, 64)).shape == (1, 1024)
