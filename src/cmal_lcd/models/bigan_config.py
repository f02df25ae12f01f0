"""The config dataclass of the BiGAN baseline (``conf/model/bigan.yaml``). No torch here: the
schema check imports it."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, Optional

from cmal_lcd.fields import node, value
from cmal_lcd.models.config import NORMS, TrainingConfig


@dataclass
class BiganOptimizer:
    """Adam learning rates of D, G and E, and its betas."""

    lr_d: float = value(gt=0.0)
    lr_g: float = value(gt=0.0)
    lr_e: Optional[float] = value(gt=0.0)       # E's own rate (null: lr_g, as G)
    beta1: float = value(ge=0.0, lt=1.0)
    beta2: float = value(ge=0.0, lt=1.0)


@dataclass
class BiganConfig(TrainingConfig):
    """The BiGAN baseline (``conf/model/bigan.yaml``)."""

    name: ClassVar[str] = "bigan"
    model_class: ClassVar[str] = "cmal_lcd.models.bigan.BiGAN"

    decoder_norm: str = value(choices=NORMS)
    discriminator_hidden: int = value(ge=1)
    prior_std: float = value(gt=0.0)
    discriminator_dropout: float = value(ge=0.0, lt=1.0)
    unary_scores: bool = value()
    optimizer: BiganOptimizer = node(BiganOptimizer)
