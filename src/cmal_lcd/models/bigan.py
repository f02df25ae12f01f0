"""BiGAN baseline (Donahue et al. 2017; paper section II-A).

Encoder ``E(x)``, generator ``G(z)`` and a joint discriminator ``D(x, z)`` that tells encoder
pairs ``(x, E(x))`` from generator pairs ``(G(z), z)``. The networks are CMAL's pyramid
without conditions, so the comparison isolates CMAL's condition direction.

- ``d_step``: ``-log D(x, E(x)) - log(1 - D(G(z), z))``;
- ``g_step`` (E and G together): the same with labels swapped (non-saturating form).

BiGAN has no reconstruction term (adding one would make it another method, an autoencoder-GAN
hybrid); ``E/recon_heldout`` (``||x - G(E(x))||^2`` on held-out frames, eval mode, no gradient)
is logged as a diagnostic, with ``E/code_norm(_heldout)`` (a prior draw has norm about
``prior_std * sqrt(code_dim)``).

Stabilisers, all optional (absent = the plain BiGAN above, computed exactly as before they
existed; ``conf/model/bigan.yaml`` says what each fixed, measured):

- ``prior_std``: the prior ``N(0, prior_std^2 I)``; D reads ``z / prior_std``;
- ``discriminator_dropout``: dropout in D's joint MLP (ALI);
- ``unary_scores``: BigBiGAN's extra scores of ``x`` alone and ``z`` alone, each with its own
  log-loss term in D's loss and (swapped) in E's and G's;
- ``optimizer.lr_e``: the encoder's own learning rate.
"""

from __future__ import annotations

from typing import Mapping

import torch
from torch.nn import functional as F

from cmal_lcd.models.base import GANModel, TrainingBatch, adam, gan_loss, set_requires_grad
from cmal_lcd.models.bigan_config import BiganConfig
from cmal_lcd.models.networks import Decoder, Encoder, JointDiscriminator

def _score_loss(scores: torch.Tensor, *, real: bool) -> torch.Tensor:
    """:func:`gan_loss` summed over the columns of ``scores`` (joint, and frame and code with
    ``unary_scores``)."""
    loss = gan_loss(scores[:, 0], real=real)
    for column in range(1, scores.shape[1]):
        loss = loss + gan_loss(scores[:, column], real=real)
    return loss


class BiGAN(GANModel):
    """Encoder, generator and joint discriminator of BiGAN.

    Parameters
    ----------
    config : BiganConfig
        ``models.bigan`` (see ``conf/model/bigan.yaml``), checked
        (:func:`cmal_lcd.models.config.model_config`).
    image_size : int
        Side of the square input frames (power of two >= 8).
    n_conditions : int
        Unused by the networks (BiGAN sees no labels); kept for a uniform interface.
    """

    name = BiganConfig.name
    label = "BiGAN"

    def __init__(self, config: BiganConfig, *, image_size: int, n_conditions: int):
        super().__init__(config, image_size=image_size, n_conditions=n_conditions)
        width, code_dim = config.width, config.code_dim
        self.encoder = Encoder(image_size=image_size, width=width, code_dim=code_dim,
                               norm=config.encoder_norm)
        self.generator = Decoder(image_size=image_size, width=width, code_dim=code_dim,
                                 norm=config.decoder_norm)
        self.discriminator = JointDiscriminator(image_size=image_size, width=width,
                                                code_dim=code_dim,
                                                hidden=config.discriminator_hidden,
                                                dropout=config.discriminator_dropout,
                                                prior_std=self.prior_std,
                                                unary=config.unary_scores)

    def encode(self, x: torch.Tensor) -> torch.Tensor:
        """``E(x)``: codes ``(N, code_dim)`` of frames ``x (N, 3, S, S)`` in [-1, 1]."""
        return self.encoder(x)

    def make_optimizers(self) -> dict[str, torch.optim.Optimizer]:
        """``D`` (``lr_d``) and ``G``: E and G together, ``lr_g``; with ``optimizer.lr_e`` (not
        null) the encoder gets its own learning rate (a second parameter group of the same Adam)."""
        opt = self.config.optimizer
        if opt.lr_e is not None:
            generator = adam(self.generator.parameters(), opt, lr=opt.lr_g)
            generator.add_param_group({"params": list(self.encoder.parameters()),
                                       "lr": opt.lr_e})
        else:
            generator = adam(list(self.encoder.parameters()) + list(self.generator.parameters()),
                             opt, lr=opt.lr_g)
        return {"D": adam(self.discriminator.parameters(), opt, lr=opt.lr_d), "G": generator}

    def d_step(self, x: torch.Tensor, z_enc: torch.Tensor, x_gen: torch.Tensor,
               noise: torch.Tensor, optimizer: torch.optim.Optimizer) -> dict[str, float]:
        """Update ``D``: encoder pairs are real, generator pairs are fake."""
        optimizer.zero_grad(set_to_none=True)
        real = self.discriminator.scores(x, z_enc.detach())
        fake = self.discriminator.scores(x_gen.detach(), noise)
        loss_real, loss_fake = _score_loss(real, real=True), _score_loss(fake, real=False)
        loss = loss_real + loss_fake
        loss.backward()
        optimizer.step()
        logs = {"D/loss": loss.item(), "D/loss_real": loss_real.item(),
                "D/loss_fake": loss_fake.item(), "D/real": torch.sigmoid(real[:, 0]).mean().item(),
                "D/fake": torch.sigmoid(fake[:, 0]).mean().item()}
        if real.shape[1] == 3:
            for column, key in ((1, "x"), (2, "z")):
                logs[f"D/{key}_real"] = torch.sigmoid(real[:, column]).mean().item()
                logs[f"D/{key}_fake"] = torch.sigmoid(fake[:, column]).mean().item()
        return logs

    def g_step(self, x: torch.Tensor, z_enc: torch.Tensor, x_gen: torch.Tensor,
               noise: torch.Tensor, optimizer: torch.optim.Optimizer) -> dict[str, float]:
        """Update ``E`` and ``G`` together to make ``D`` swap its labels.

        ``E/adv`` and ``G/adv`` are the joint score's terms (comparable with and without
        ``unary_scores``); ``E/adv_z`` and ``G/adv_x`` the unary terms when on.
        """
        optimizer.zero_grad(set_to_none=True)
        set_requires_grad(self.discriminator, False)
        logs = {}
        try:
            enc, gen = self.discriminator.scores(x, z_enc), self.discriminator.scores(x_gen, noise)
            e_adv = gan_loss(enc[:, 0], real=False)
            g_adv = gan_loss(gen[:, 0], real=True)
            loss = e_adv + g_adv
            if enc.shape[1] == 3:
                # unary terms: only the code score of encoder pairs depends on E and only the
                # frame score of generator pairs on G (the other two are constants here)
                e_unary = gan_loss(enc[:, 2], real=False)
                g_unary = gan_loss(gen[:, 1], real=True)
                loss = loss + e_unary + g_unary
                logs.update({"E/adv_z": e_unary.item(), "G/adv_x": g_unary.item()})
            loss.backward()
            optimizer.step()
        finally:
            set_requires_grad(self.discriminator, True)
        logs.update({"G/adv": g_adv.item(), "E/adv": e_adv.item(), "G/loss": loss.item(),
                     "E/code_norm": z_enc.detach().norm(dim=1).mean().item()})
        return logs

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
        """``E/recon_heldout``: ``||x - G(E(x))||^2`` on held-out frames (eval mode), and
        ``E/code_norm_heldout``: mean ``||E(x)||`` (a prior draw has norm about
        ``prior_std * sqrt(code_dim)``)."""
        was_training = self.training
        self.eval()
        try:
            z = self.encoder(x)
            mse = F.mse_loss(self.generator(z), x).item()
        finally:
            self.train(was_training)
        return {"E/recon_heldout": mse, "E/code_norm_heldout": z.norm(dim=1).mean().item()}

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
