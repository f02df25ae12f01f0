"""The config dataclass of the BiGAN baseline (``conf/model/bigan.yaml``). No torch here: the
schema check imports it."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from cmal_lcd.fields import node, value
from cmal_lcd.models.config import TrainingConfig


@dataclass
class BiganOptimizer:
    """Adam learning rates of D, G and E, and its betas."""

    lr_d: float = value(gt=0.0)
    lr_g: float = value(gt=0.0)
    lr_e: float = value(gt=0.0)
    beta1: float = value(ge=0.0, lt=1.0)
    beta2: float = value(ge=0.0, lt=1.0)


@dataclass
class BiganConfig(TrainingConfig):
    """The BiGAN baseline (``conf/model/bigan.yaml``)."""

    name: ClassVar[str] = "bigan"
    model_class: ClassVar[str] = "cmal_lcd.models.bigan.BiGAN"

    discriminator_hidden: int = value(ge=1)
    prior_std: float = value(gt=0.0)
    discriminator_dropout: float = value(ge=0.0, lt=1.0)
    unary_scores: bool = value()
    optimizer: BiganOptimizer = node(BiganOptimizer)
