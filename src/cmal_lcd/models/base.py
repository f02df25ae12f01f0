"""What the shared training loop needs from a model, and the batch it hands to it.

A model is an ``nn.Module`` that also knows its own update rule, split StarGAN-style into
named steps (``c_step``, ``d_step``, ``g_step``) called by :meth:`GANModel.training_step`.
The loop in :mod:`cmal_lcd.models.training` is the same for every model: it draws a
:class:`TrainingBatch`, calls ``training_step``, checks the losses, logs, samples and
checkpoints.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

import torch
from torch import nn
from torch.nn import functional as F

from cmal_lcd.models import MODEL_CONFIGS
from cmal_lcd.models.config import TrainingConfig


@dataclass(frozen=True)
class TrainingBatch:
    """One iteration's inputs, drawn by the loop from ``(seed, iteration)``.

    Attributes
    ----------
    x : Tensor, float32, shape (N, 3, S, S)
        Real frames in ``[-1, 1]``.
    condition : Tensor, int64, shape (N,)
        Weather label of each frame (branch A).
    target : Tensor, int64, shape (N,)
        Another condition for each frame (branch B); equals ``condition`` when there is
        only one condition.
    noise : Tensor, float32, shape (N, code_dim)
        Codes drawn from the prior ``P_Z = N(0, prior_std^2 I)`` for the generated frames
        (the loop scales standard normal draws by :attr:`GANModel.prior_std`); also the
        "real" side of CMAL's code discriminator ``D_z``.
    positive : Tensor, float32, shape (N, 3, S, S), optional
        For a model with a place rule (:attr:`GANModel.place_rule`): for each frame, a training
        frame of another condition at the same place (the frame itself where it has none);
        None otherwise.
    positive_condition : Tensor, int64, shape (N,), optional
        The weather label of each ``positive``.
    has_positive : Tensor, bool, shape (N,), optional
        Which frames have a positive (the others take no part in the place term).
    """

    x: torch.Tensor
    condition: torch.Tensor
    target: torch.Tensor
    noise: torch.Tensor
    positive: torch.Tensor | None = None
    positive_condition: torch.Tensor | None = None
    has_positive: torch.Tensor | None = None


def gan_loss(logits: torch.Tensor, *, real: bool) -> torch.Tensor:
    """The GAN log-loss: ``-log D`` for real targets, ``-log(1 - D)`` for fake ones.

    Parameters
    ----------
    logits : Tensor, shape (N,)
        Discriminator logits (``D = sigmoid(logits)``).

    Returns
    -------
    Tensor, scalar
        Mean over the batch; ``softplus`` keeps it finite for large logits.
    """
    return F.softplus(-logits).mean() if real else F.softplus(logits).mean()


def set_requires_grad(module: nn.Module, flag: bool) -> None:
    """Freeze or unfreeze every parameter of ``module``."""
    for p in module.parameters():
        p.requires_grad_(flag)


class GANModel(nn.Module):
    """Interface of the trainable models (CMAL and BiGAN).

    Attributes
    ----------
    config : TrainingConfig
        The model's config: an instance of its config dataclass, checked
        (:func:`cmal_lcd.models.config.model_config`).
    image_size, n_conditions, code_dim : int
    prior_std : float
        Standard deviation per dimension of the code prior ``P_Z = N(0, prior_std^2 I)``
        (config ``prior_std``).
    conditional : bool
        The model learns every condition (its config dataclass's ``conditional``).
    name : str
        Class attribute: the model's name, that of its config dataclass
        (:data:`cmal_lcd.models.MODEL_CONFIGS`, whose fields are the keys its node may hold).
    """

    name: str = ""

    def __init__(self, config: TrainingConfig, *, image_size: int, n_conditions: int):
        super().__init__()
        self.config = config
        self.image_size = int(image_size)
        self.n_conditions = int(n_conditions)
        self.code_dim = config.code_dim
        # a model without a prior (the place encoder) draws the loop's unused noise from N(0, I)
        self.prior_std = getattr(config, "prior_std", 1.0)

    @property
    def conditional(self) -> bool:
        """Whether the model learns every condition (``MODEL_CONFIGS[name].conditional``)."""
        return MODEL_CONFIGS[self.name].conditional

    @property
    def device(self) -> torch.device:
        return next(self.parameters()).device

    @property
    def place_rule(self):
        """The ``place`` node (:class:`~cmal_lcd.models.cmal_config.PlaceConfig`) when the
        model trains with place supervision (the loop then draws ``TrainingBatch.positive``);
        None by default."""
        return None

    @property
    def label(self) -> str:
        """The row label of its codes in every table and legend: what was trained, with which
        objective when the model has several (default: its name)."""
        return self.name

    def encode(self, x: torch.Tensor) -> torch.Tensor:
        """Codes of frames ``x (N, 3, S, S)`` in ``[-1, 1]`` -> ``(N, code_dim)``."""
        raise NotImplementedError

    def make_optimizers(self) -> dict[str, torch.optim.Optimizer]:
        """One optimiser per updated module group, keyed by name (``D``, ``G``, ``C``...)."""
        raise NotImplementedError

    def training_step(self, batch: TrainingBatch, optimizers: Mapping[str, torch.optim.Optimizer],
                      *, diagnostics: bool = False) -> dict[str, float]:
        """One update of every module; returns the logged values (``D/...``, ``G/...``...).

        ``diagnostics`` asks for extra values that cost computation (logged iterations only).
        """
        raise NotImplementedError

    @torch.no_grad()
    def heldout_metrics(self, x: torch.Tensor, condition: torch.Tensor) -> dict[str, float]:
        """Values measured on held-out frames (e.g. ``C/acc_heldout``); eval mode."""
        raise NotImplementedError

    @torch.no_grad()
    def sample_rows(self, x: torch.Tensor, condition: torch.Tensor,
                    noise: torch.Tensor) -> list[torch.Tensor]:
        """Rows of the sample grid for a fixed batch: each ``(n, 3, S, S)`` in ``[-1, 1]``."""
        raise NotImplementedError


def adam(params, optimizer: Any, *, lr: float) -> torch.optim.Adam:
    """Adam at ``lr`` with the ``(beta1, beta2)`` of a model's ``optimizer`` node.

    ``foreach=True``: the multi-tensor implementation, bitwise identical to the default
    per-parameter loop on CPU (checked) and about twice as fast on the 4.5M parameters of
    CMAL's En+De (one CPU thread: 44 -> 22 ms per step). ``fused=True`` would be faster still
    but rounds differently, so a rerun would no longer reproduce earlier weights.
    """
    return torch.optim.Adam(params, lr=lr, betas=(optimizer.beta1, optimizer.beta2),
                            foreach=True)
