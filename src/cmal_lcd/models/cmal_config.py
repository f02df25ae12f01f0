"""The config dataclasses of CMAL (``conf/model/cmal.yaml``, objective weights from
``conf/objective/``), of CMAL with place supervision (``cmal_place``, an extension) and of its
ablation without the GAN (``place_encoder``). No torch here: the schema check imports it."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, Optional

from cmal_lcd.fields import node, value
from cmal_lcd.models.config import NORMS, TrainingConfig

#: The condition fed to En when encoding a frame for matching: the one-hot of C's decision, or
#: C's probabilities.
ENCODE_CONDITIONS = ("argmax", "softmax")
#: D's objective: ``bce``, the paper's log loss (non-saturating for En/De); ``hinge``.
ADVERSARIAL_LOSSES = ("bce", "hinge")
#: How ``loss_weights.prior`` pulls the codes to the prior (eq. 7): ``adversarial``, the code
#: discriminator D_z (an adversarial autoencoder); ``mmd``, a kernel two-sample distance.
PRIOR_DIVERGENCES = ("adversarial", "mmd")


@dataclass
class LossWeights:
    """CMAL objective weights (eq. 12); ``prior`` and ``adversary`` come from ``objective``."""

    adv: float = value(ge=0.0)
    recon: float = value(ge=0.0)
    latent: float = value(ge=0.0)
    prior: float = value(ge=0.0)
    adversary: float = value(ge=0.0)


@dataclass
class PlaceLossWeights(LossWeights):
    """CMAL's weights and the place term's (``cmal_place``; an extension)."""

    place: float = value(gt=0.0)


@dataclass
class PlaceConfig:
    """Place supervision (cmal_lcd.models.places): which training frames are the same place."""

    radius: float = value(gt=0.0)                # frames.csv x, y units (metres in the world)
    heading_deg: float = value(gt=0.0, le=180.0)
    temperature: float = value(gt=0.0)


@dataclass
class CmalOptimizer:
    """Adam learning rates of D, En+De and C, and its betas."""

    lr_d: float = value(gt=0.0)
    lr_g: float = value(gt=0.0)
    lr_c: float = value(gt=0.0)
    beta1: float = value(ge=0.0, lt=1.0)
    beta2: float = value(ge=0.0, lt=1.0)
    lr_en: Optional[float] = value(gt=0.0)       # En's own rate (null: lr_g)


@dataclass
class CmalConfig(TrainingConfig):
    """CMAL (``conf/model/cmal.yaml``): the paper's four modules and the eq. 7/8 extras."""

    name: ClassVar[str] = "cmal"
    model_class: ClassVar[str] = "cmal_lcd.models.cmal.CMAL"
    # conf/objective/<name>.yaml sets loss_weights.{prior,adversary}
    groups: ClassVar[dict[str, type]] = {"objective": LossWeights}
    conditional: ClassVar[bool] = True           # learns by translating between the conditions

    classifier_width: int = value(ge=1)
    decoder_norm: str = value(choices=NORMS)
    encode_condition: str = value(choices=ENCODE_CONDITIONS)
    loss_weights: LossWeights = node(LossWeights)
    prior_std: float = value(gt=0.0)
    code_critic_hidden: int = value(ge=1)
    code_critic_steps: int = value(ge=1)
    optimizer: CmalOptimizer = node(CmalOptimizer)
    # the paper-scale recipe's switches (issue 36; off: the paper's update rule)
    adversarial_loss: str = value(choices=ADVERSARIAL_LOSSES)
    r1_gamma: float = value(ge=0.0)              # R1 penalty on D's real frames (0: off)
    ema_decay: float = value(ge=0.0, lt=1.0)     # En's moving average encodes (0: off)
    prior_divergence: str = value(choices=PRIOR_DIVERGENCES)  # eq. 7 by D_z or by MMD


@dataclass
class CmalPlaceConfig(CmalConfig):
    """CMAL + place supervision (``conf/model/cmal_place.yaml``; an extension, not the paper)."""

    name: ClassVar[str] = "cmal_place"
    model_class: ClassVar[str] = "cmal_lcd.models.cmal.CMALPlace"

    loss_weights: PlaceLossWeights = node(PlaceLossWeights)
    place: PlaceConfig = node(PlaceConfig)


@dataclass
class PlaceEncoderOptimizer:
    """Adam learning rates of En (lr_g) and C (lr_c), and its betas."""

    lr_g: float = value(gt=0.0)
    lr_c: float = value(gt=0.0)
    beta1: float = value(ge=0.0, lt=1.0)
    beta2: float = value(ge=0.0, lt=1.0)


@dataclass
class PlaceEncoderConfig(TrainingConfig):
    """The place encoder ablation (``conf/model/place_encoder.yaml``): CMAL's C and En, the
    place term alone."""

    name: ClassVar[str] = "place_encoder"
    model_class: ClassVar[str] = "cmal_lcd.models.cmal.PlaceEncoder"
    conditional: ClassVar[bool] = True           # CMAL's classifier and conditional encoder

    classifier_width: int = value(ge=1)
    encode_condition: str = value(choices=ENCODE_CONDITIONS)
    place: PlaceConfig = node(PlaceConfig)
    optimizer: PlaceEncoderOptimizer = node(PlaceEncoderOptimizer)
