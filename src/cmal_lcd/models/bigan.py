"""BiGAN baseline (Donahue et al. 2017; paper section II-A).

Encoder ``E(x)``, generator ``G(z)`` and a joint discriminator ``D(x, z)`` that tells encoder
pairs ``(x, E(x))`` from generator pairs ``(G(z), z)``. The networks are CMAL's pyramid
without conditions, so the comparison isolates CMAL's condition direction.

- ``d_step``: ``-log D(x, E(x)) - log(1 - D(G(z), z))``;
- ``g_step`` (E and G together): the same with labels swapped (non-saturating form).

BiGAN has no reconstruction term; ``E/recon_heldout`` (``||x - G(E(x))||^2`` on held-out
frames, eval mode, no gradient) is logged as a diagnostic.
"""

from __future__ import annotations

from typing import Any, Mapping

import torch
from torch.nn import functional as F

from cmal_lcd.models.base import (GANModel, TrainingBatch, gan_loss, optimizer_from_config,
                                  require_keys, set_requires_grad)
from cmal_lcd.models.networks import Decoder, Encoder, JointDiscriminator

#: Keys ``conf/model/bigan.yaml`` must provide for the networks.
BIGAN_KEYS = ("code_dim", "width", "encoder_norm", "decoder_norm", "discriminator_hidden",
              "optimizer")


class BiGAN(GANModel):
    """Encoder, generator and joint discriminator of BiGAN.

    Parameters
    ----------
    config : mapping
        ``models.bigan`` (see ``conf/model/bigan.yaml``).
    image_size : int
        Side of the square input frames (power of two >= 8).
    n_conditions : int
        Unused by the networks (BiGAN sees no labels); kept for a uniform interface.
    """

    name = "bigan"

    def __init__(self, config: Mapping[str, Any], *, image_size: int, n_conditions: int):
        require_keys(config, BIGAN_KEYS, where="models.bigan")
        super().__init__(config, image_size=image_size, n_conditions=n_conditions)
        width, code_dim = int(config["width"]), int(config["code_dim"])
        self.encoder = Encoder(image_size=image_size, width=width, code_dim=code_dim,
                               norm=config["encoder_norm"])
        self.generator = Decoder(image_size=image_size, width=width, code_dim=code_dim,
                                 norm=config["decoder_norm"])
        self.discriminator = JointDiscriminator(image_size=image_size, width=width,
                                                code_dim=code_dim,
                                                hidden=int(config["discriminator_hidden"]))

    def encode(self, x: torch.Tensor) -> torch.Tensor:
        """``E(x)``: codes ``(N, code_dim)`` of frames ``x (N, 3, S, S)`` in [-1, 1]."""
        return self.encoder(x)

    def make_optimizers(self) -> dict[str, torch.optim.Optimizer]:
        cfg = self.config
        return {
            "D": optimizer_from_config(self.discriminator.parameters(), cfg, "lr_d"),
            "G": optimizer_from_config(list(self.encoder.parameters())
                                       + list(self.generator.parameters()), cfg, "lr_g"),
        }

    def d_step(self, x: torch.Tensor, z_enc: torch.Tensor, x_gen: torch.Tensor,
               noise: torch.Tensor, optimizer: torch.optim.Optimizer) -> dict[str, float]:
        """Update ``D``: encoder pairs are real, generator pairs are fake."""
        optimizer.zero_grad(set_to_none=True)
        real = self.discriminator(x, z_enc.detach())
        fake = self.discriminator(x_gen.detach(), noise)
        loss_real, loss_fake = gan_loss(real, real=True), gan_loss(fake, real=False)
        loss = loss_real + loss_fake
        loss.backward()
        optimizer.step()
        return {"D/loss": loss.item(), "D/loss_real": loss_real.item(),
                "D/loss_fake": loss_fake.item(), "D/real": torch.sigmoid(real).mean().item(),
                "D/fake": torch.sigmoid(fake).mean().item()}

    def g_step(self, x: torch.Tensor, z_enc: torch.Tensor, x_gen: torch.Tensor,
               noise: torch.Tensor, optimizer: torch.optim.Optimizer) -> dict[str, float]:
        """Update ``E`` and ``G`` together to make ``D`` swap its labels."""
        optimizer.zero_grad(set_to_none=True)
        set_requires_grad(self.discriminator, False)
        try:
            e_adv = gan_loss(self.discriminator(x, z_enc), real=False)
            g_adv = gan_loss(self.discriminator(x_gen, noise), real=True)
            loss = e_adv + g_adv
            loss.backward()
            optimizer.step()
        finally:
            set_requires_grad(self.discriminator, True)
        return {"G/adv": g_adv.item(), "E/adv": e_adv.item(), "G/loss": loss.item()}

    def training_step(self, batch: TrainingBatch, optimizers: Mapping[str, torch.optim.Optimizer],
                      *, diagnostics: bool = False) -> dict[str, float]:
        """One forward of E and G shared by ``d_step`` and ``g_step``."""
        z_enc = self.encoder(batch.x)
        x_gen = self.generator(batch.noise)
        logs = self.d_step(batch.x, z_enc, x_gen, batch.noise, optimizers["D"])
        logs.update(self.g_step(batch.x, z_enc, x_gen, batch.noise, optimizers["G"]))
        return logs

    @torch.no_grad()
    def heldout_metrics(self, x: torch.Tensor, condition: torch.Tensor) -> dict[str, float]:
        """``E/recon_heldout``: ``||x - G(E(x))||^2`` on held-out frames (eval mode)."""
        was_training = self.training
        self.eval()
        try:
            mse = F.mse_loss(self.generator(self.encoder(x)), x).item()
        finally:
            self.train(was_training)
        return {"E/recon_heldout": mse}

    @torch.no_grad()
    def sample_rows(self, x: torch.Tensor, condition: torch.Tensor,
                    noise: torch.Tensor) -> list[torch.Tensor]:
        """Rows: real frames, ``G(E(x))``, ``G(n)``."""
        was_training = self.training
        self.eval()
        try:
            rows = [x, self.generator(self.encoder(x)), self.generator(noise)]
        finally:
            self.train(was_training)
        return rows
