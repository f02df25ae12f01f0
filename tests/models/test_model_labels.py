"""Every learned row says which objective it is: a trained model labels its own codes."""

import pytest
from omegaconf import OmegaConf

from cmal_lcd.config import CONF_DIR
from cmal_lcd.models import build_model
from model_helpers import tiny_config


@pytest.mark.parametrize("objective, label", [
    ("paper", "CMAL (paper objective, eqs. 9-12)"),
    ("prior", "CMAL (+ eq. 7 prior)"),
    ("adversary", "CMAL (+ eq. 8 adversary)"),
    ("prior_adversary", "CMAL (+ eq. 7 prior, eq. 8 adversary)"),
])
def test_a_cmal_model_is_labelled_by_the_objective_it_was_trained_with(objective, label):
    weights = OmegaConf.to_container(OmegaConf.load(CONF_DIR / "objective" / f"{objective}.yaml"))
    model = build_model("cmal", tiny_config("cmal", loss_weights=weights), image_size=16,
                        n_conditions=3)
    assert model.label == label


def test_the_latent_cycle_is_named_an_extension_and_bigan_is_the_baseline():
    cmal = build_model("cmal", tiny_config("cmal", loss_weights={"latent": 0.5}), image_size=16,
                       n_conditions=3)
    assert cmal.label == "CMAL (+ latent cycle, an extension)"
    assert build_model("bigan", tiny_config("bigan"), image_size=16, n_conditions=3).label \
        == "BiGAN"
