"""conf/model/*.yaml: composed under models.<name>, accepted by the loop and build_model."""

import pytest
import torch
from omegaconf import OmegaConf

from cmal_lcd.config import CONF_DIR, compose
from cmal_lcd.models import MODEL_NAMES, build_model
from cmal_lcd.models.training import training_settings


def test_every_model_has_a_config_file():
    assert {p.stem for p in (CONF_DIR / "model").glob("*.yaml")} == set(MODEL_NAMES)


@pytest.mark.parametrize("name", ["cmal", "bigan"])
def test_composed_config_has_a_trainable_node_per_model(name):
    cfg = compose([])
    node = cfg.models[name]
    assert node == OmegaConf.load(CONF_DIR / "model" / f"{name}.yaml")
    settings = training_settings(node)
    assert settings.image_size == 64 and node.code_dim == 1024
    assert int(cfg.runtime.threads) >= 1
    model = build_model(name, node, image_size=settings.image_size,
                        n_conditions=3, seed=0)
    assert model.encode(torch.zeros(1, 3, 64, 64)).shape == (1, 1024)
