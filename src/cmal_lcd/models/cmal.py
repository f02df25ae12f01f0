"""CMAL: condition directed multi-domain adversarial learning (paper section III-B).

Four modules (:mod:`cmal_lcd.models.networks` says how the condition enters each):

- ``C(x)``: weather classifier, supervised by the weather label (the only label used);
- ``En(x | c)``: encoder to a 1024-d code;
- ``De(z | c)``: decoder from a code under a condition;
- ``D(x | c)``: conditional (projection) discriminator.

One training step (Fig. 5, eqs. 9-12)
-------------------------------------
For a batch of real frames ``x`` of conditions ``a`` (branch A) and, per frame, another
condition ``b`` drawn uniformly (branch B):

- encode ``z = En(x | a)``; decode ``R-A = De(z | a)`` (reconstruction) and
  ``R-B = De(z | b)`` (translation, Fig. 5 step 2); generate ``G-A = De(n | a)`` and
  ``G-B = De(n | b)`` from the same noise ``n``;
- ``d_step``: ``D`` learns to score real frames high under their own condition and the four
  synthetic batches low under the condition they were made for (eqs. 9-10, max over D);
- ``g_step``: ``En`` and ``De`` learn to fool ``D`` on the four synthetic batches
  (non-saturating form of the min over En/De) plus ``recon * ||x - R-A||^2`` (eq. 11);
- ``c_step``: cross-entropy of ``C`` against the weather label.

Not in the paper, off by default (weight 0 = the module is not even built, so the paper's
objective is computed exactly as without these options):

- ``loss_weights.latent`` adds a latent cycle term ``||En(R-B | b) - Z-A||^2`` (see
  :meth:`CMAL.g_step`);
- ``loss_weights.prior`` enforces eq. 7, ``P_E(Z | c, X) = P_Z(Z)`` for every condition ``c``,
  which eqs. 9-12 only imply at their joint optimum and never push towards directly (``D``
  sees frames, not codes, so nothing ties the code distribution to the prior and the
  generated branch ``De(n|c)`` may be fed codes of another scale than ``De(En(x|c)|c)``).
  A conditional code discriminator ``D_z(z | c)`` (adversarial autoencoder, Makhzani et al.
  2016) learns to tell prior draws ``n ~ P_Z`` from codes ``En(x | c)`` under ``c``
  (:meth:`CMAL.dz_step`, optimiser ``Dz`` with ``lr_d``); the encoder learns to fool it
  (non-saturating, ``E/prior``); ``prior_divergence: mmd`` replaces ``D_z`` with a kernel
  MMD between the codes and prior draws of each condition (:func:`mmd_to_prior`, as in the
  Wasserstein auto-encoder), a switch of the paper-scale recipe;
- ``loss_weights.place`` (:class:`CMALPlace`, model ``cmal_place``) adds place supervision:
  InfoNCE between the codes of training frames of the same place under two weathers
  (:mod:`cmal_lcd.models.places`), a label the paper never uses. :class:`PlaceEncoder`
  (``place_encoder``) is its ablation: the same classifier and encoder trained with the place
  term alone, no decoder and no discriminator;
- ``loss_weights.adversary`` asks directly for eq. 8 (codes independent of the weather): a
  latent adversary ``A(z)`` learns to predict the weather label from detached codes
  (:meth:`CMAL.adversary_step`, optimiser ``A`` with ``lr_d``); the encoder is pushed to make
  its prediction uniform (``E/adversary``, see :meth:`CMAL.g_step` for why not gradient
  reversal).

``code_critic_steps`` updates of ``D_z`` and ``A`` per iteration (on the same detached codes)
let the critics keep up with the encoder: one Adam step of ``En`` moves every code by a fixed
amount (~0.18 per dimension at lr 2e-4) whatever the gradient size, and a critic updated once
per step ends up chasing the codes instead of judging them (measured in ``conf/model/cmal.yaml``).

``prior_std`` is the per-dimension standard deviation of ``P_Z = N(0, prior_std^2 I)``; the
training loop draws ``TrainingBatch.noise`` from it (see ``conf/model/cmal.yaml`` for the
measured code scale behind its value).

Eq. 12 sums ``V_A + V_B``. Both branches draw their real frames from the same distribution
(the training frames of a random condition), so the real term of ``V_B`` is estimated by the
same real batch; the loss of ``D`` is ``(V_A + V_B) / 2``:
``-log D(x|a) - 1/2 sum_{fake in G-A, G-B, R-A, R-B} log(1 - D(fake|its condition))``.

During training ``En`` and ``De`` get the true label as condition (every training frame has
one; feeding ``C``'s early mistakes would only add noise). For matching, a frame is encoded
under the classifier's decision, ``En(x | onehot(argmax C(x)))`` (``encode_condition:
argmax``): ``En`` only ever saw one-hot conditions, so a soft mixture would be an input it
was never trained on; ``softmax`` is available to test that choice.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import replace
from typing import Mapping

import numpy as np
import torch
from torch.nn import functional as F
from torch.optim.swa_utils import AveragedModel, get_ema_multi_avg_fn

from cmal_lcd.models.base import GANModel, TrainingBatch, adam, gan_loss, set_requires_grad
from cmal_lcd.models.cmal_config import (CmalConfig, CmalPlaceConfig, PlaceConfig,
                                         PlaceEncoderConfig)
from cmal_lcd.models.images import preprocess, to_uint8
from cmal_lcd.models.networks import (CodeClassifier, CodeDiscriminator, ConditionClassifier,
                                      Decoder, Encoder, ProjectionDiscriminator)
from cmal_lcd.models.places import info_nce

#: What each term beyond the paper's objective (eqs. 9-12) is called in a row label.
OBJECTIVE_TERMS = (("prior", "eq. 7 prior"), ("adversary", "eq. 8 adversary"),
                   ("latent", "latent cycle, an extension"))


def r1_penalty(logits: torch.Tensor, real: torch.Tensor) -> torch.Tensor:
    """R1 (Mescheder et al. 2018): ``mean_i ||d logits_i / d real_i||^2`` over the real frames
    ``real (N, 3, S, S)`` (which require grad), differentiable w.r.t. D's weights."""
    (grad,) = torch.autograd.grad(logits.sum(), real, create_graph=True)
    return grad.pow(2).flatten(1).sum(dim=1).mean()


#: Scales of the inverse multiquadric kernels whose sum :func:`mmd_to_prior` uses, times
#: ``2 * code_dim * prior_std^2`` (the expected squared distance of two prior draws); those of
#: the Wasserstein auto-encoder (Tolstikhin et al. 2018), which pulled its codes to the same
#: Gaussian prior this way.
MMD_SCALES = (0.1, 0.2, 0.5, 1.0, 2.0, 5.0, 10.0)


def mmd_squared(x: torch.Tensor, y: torch.Tensor, *, scale: float) -> torch.Tensor:
    """The unbiased estimate of MMD^2 between samples ``x (n, d)`` and ``y (m, d)`` (n, m >= 2)
    under the kernel ``sum_s C_s / (C_s + ||a - b||^2)``, ``C_s = s * scale``
    (:data:`MMD_SCALES`). Zero in expectation when both come from one distribution (so one
    batch's value can be slightly negative)."""
    n, m = len(x), len(y)
    distances = torch.cdist(torch.cat([x, y]), torch.cat([x, y])).pow(2)
    kernel = sum(s * scale / (s * scale + distances) for s in MMD_SCALES)
    kxx, kyy, kxy = kernel[:n, :n], kernel[n:, n:], kernel[:n, n:]
    return ((kxx.sum() - kxx.diagonal().sum()) / (n * (n - 1))
            + (kyy.sum() - kyy.diagonal().sum()) / (m * (m - 1)) - 2 * kxy.mean())


def mmd_to_prior(code: torch.Tensor, noise: torch.Tensor, condition: torch.Tensor, *,
                 prior_std: float) -> torch.Tensor:
    """Eq. 7 by MMD: for each condition ``c`` with at least two frames in the batch,
    :func:`mmd_squared` between its codes ``code[condition == c] (n_c, d)`` and as many prior
    draws ``noise[condition == c]``, averaged with weights ``n_c``."""
    scale = 2.0 * code.shape[1] * prior_std ** 2
    total, count = code.sum() * 0.0, 0
    for c in torch.unique(condition):
        keep = condition == c
        n = int(keep.sum())
        if n >= 2:
            total = total + n * mmd_squared(code[keep], noise[keep], scale=scale)
            count += n
    return total / max(count, 1)


class CMAL(GANModel):
    """The four CMAL modules and their update rule.

    Parameters
    ----------
    config : mapping
        ``models.cmal`` (see ``conf/model/cmal.yaml``).
    image_size : int
        Side of the square input frames (power of two >= 8).
    n_conditions : int
        Number of weather conditions (>= 1; translation needs >= 2).
    """

    name = CmalConfig.name

    @property
    def label(self) -> str:
        """``CMAL (paper objective, eqs. 9-12)``, or the terms it adds, e.g. ``CMAL (+ eq. 7
        prior, eq. 8 adversary)`` (:data:`OBJECTIVE_TERMS` with a weight above 0), and the
        recipe switches that are on, e.g. ``CMAL (eqs. 9-12) + recipe (hinge loss, EMA
        0.999)`` (then never "paper objective": not the paper's update rule)."""
        added = [text for key, text in OBJECTIVE_TERMS if self.weights[key] > 0]
        recipe = self.recipe_terms()
        base = (f"CMAL (+ {', '.join(added)})" if added else
                "CMAL (eqs. 9-12)" if recipe else "CMAL (paper objective, eqs. 9-12)")
        if recipe:
            base += f" + recipe ({', '.join(recipe)})"
        return f"{base} + place (extension)" if self._place_rule is not None else base

    def recipe_terms(self) -> list[str]:
        """The recipe switches that are on, as a row label names them."""
        lr_en = self.config.optimizer.lr_en
        return [text for on, text in (
            (self.adversarial_loss == "hinge", "hinge loss"),
            (self.r1_gamma > 0, f"R1 {self.r1_gamma:g}"),
            (self.encoder_ema is not None, f"EMA {self.config.ema_decay:g}"),
            (lr_en is not None, f"En lr {lr_en}"),
            (self.weights["prior"] > 0 and self.prior_divergence == "mmd", "MMD prior")) if on]

    @property
    def place_rule(self) -> PlaceConfig | None:
        """The ``place`` node of a model trained with the place term, else None."""
        return self._place_rule

    def __init__(self, config: CmalConfig, *, image_size: int, n_conditions: int):
        if n_conditions < 1:
            raise ValueError(f"n_conditions: expected >= 1, got {n_conditions}")
        super().__init__(config, image_size=image_size, n_conditions=n_conditions)
        # the objective's weights (eq. 12; the place term's for cmal_place)
        self.weights = dataclasses.asdict(config.loss_weights)
        self._place_rule = getattr(config, "place", None)
        self._build_classifier_and_encoder(config)
        self.decoder = Decoder(image_size=image_size, width=config.width,
                               code_dim=config.code_dim, n_conditions=n_conditions,
                               norm=config.decoder_norm)
        self.discriminator = ProjectionDiscriminator(image_size=image_size, width=config.width,
                                                     n_conditions=n_conditions)
        # Built after the paper's four modules (their initial weights do not depend on these
        # options) and only when used (a paper-objective model has the same state_dict keys).
        self.code_critic_steps = config.code_critic_steps
        self.prior_divergence = config.prior_divergence
        self.code_discriminator = CodeDiscriminator(
            code_dim=config.code_dim, n_conditions=n_conditions,
            hidden=config.code_critic_hidden, prior_std=self.prior_std) if (
                self.weights["prior"] > 0 and self.prior_divergence == "adversarial") else None
        self.adversary = CodeClassifier(
            code_dim=config.code_dim, n_conditions=n_conditions,
            hidden=config.code_critic_hidden,
            prior_std=self.prior_std) if self.weights["adversary"] > 0 else None
        self._build_recipe(config)

    def _build_recipe(self, config: CmalConfig) -> None:
        """The paper-scale recipe's switches (issue 36; off: the paper's update rule, bit for
        bit): ``adversarial_loss``, ``r1_gamma``, ``ema_decay`` (an EMA copy of En, built last
        so that no other initial weight moves, and only when on)."""
        self.adversarial_loss = config.adversarial_loss
        self.r1_gamma = config.r1_gamma
        # En's exponential moving average, which then encodes (None: En itself)
        self.encoder_ema = AveragedModel(
            self.encoder, multi_avg_fn=get_ema_multi_avg_fn(config.ema_decay),
            use_buffers=True) if config.ema_decay > 0 else None

    def _build_classifier_and_encoder(self, config: CmalConfig | PlaceEncoderConfig) -> None:
        """``C`` then ``En`` (in this order: the seed gives every model built from it the same
        initial classifier and encoder)."""
        self.classifier = ConditionClassifier(image_size=self.image_size,
                                              width=config.classifier_width,
                                              n_conditions=self.n_conditions)
        self.encoder = Encoder(image_size=self.image_size, width=config.width,
                               code_dim=config.code_dim, n_conditions=self.n_conditions,
                               norm=config.encoder_norm)

    # ------------------------------------------------------------------ inference
    def one_hot(self, condition: torch.Tensor) -> torch.Tensor:
        """Labels ``(N,)`` int64 -> one-hot ``(N, n_conditions)`` float32."""
        return F.one_hot(condition, self.n_conditions).float()

    def classify(self, x: torch.Tensor) -> torch.Tensor:
        """Classifier logits ``(N, n_conditions)`` for frames ``x (N, 3, S, S)``."""
        return self.classifier(x)

    def encode_condition(self, x: torch.Tensor) -> torch.Tensor:
        """The condition a frame is encoded under: ``(N, n_conditions)`` from ``C(x)``."""
        logits = self.classifier(x)
        if self.config.encode_condition == "softmax":
            return logits.softmax(dim=1)
        return self.one_hot(logits.argmax(dim=1))

    def encode(self, x: torch.Tensor) -> torch.Tensor:
        """``En(x | C(x))``: codes ``(N, code_dim)`` of frames ``x (N, 3, S, S)`` in [-1, 1];
        with ``ema_decay > 0``, ``En``'s exponential moving average encodes."""
        encoder = self.encoder_ema.module if self.encoder_ema is not None else self.encoder
        return encoder(x, self.encode_condition(x))

    def decode(self, z: torch.Tensor, condition: torch.Tensor) -> torch.Tensor:
        """``De(z | c)``: frames ``(N, 3, S, S)`` from codes and labels ``(N,)``."""
        return self.decoder(z, self.one_hot(condition))

    # ------------------------------------------------------------------ training
    def make_optimizers(self) -> dict[str, torch.optim.Optimizer]:
        """``C``, ``D``, ``G`` (En + De); ``Dz`` and ``A`` (``lr_d``) when those modules exist."""
        opt = self.config.optimizer
        optimizers = {
            "C": adam(self.classifier.parameters(), opt, lr=opt.lr_c),
            "D": adam(self.discriminator.parameters(), opt, lr=opt.lr_d),
            "G": adam(self._generator_parameters(), opt, lr=opt.lr_g),
        }
        if self.code_discriminator is not None:
            optimizers["Dz"] = adam(self.code_discriminator.parameters(), opt, lr=opt.lr_d)
        if self.adversary is not None:
            optimizers["A"] = adam(self.adversary.parameters(), opt, lr=opt.lr_d)
        return optimizers

    def _generator_parameters(self) -> list:
        """En's and De's parameters for the ``G`` optimiser: one group at ``lr_g``, or, with
        ``optimizer.lr_en`` set, En's group at ``lr_en`` and De's at ``lr_g`` (a lower rate for
        the wider code head of the paper-scale widths)."""
        lr_en = self.config.optimizer.lr_en
        if lr_en is None:
            return list(self.encoder.parameters()) + list(self.decoder.parameters())
        return [{"params": list(self.encoder.parameters()), "lr": lr_en},
                {"params": list(self.decoder.parameters())}]

    def synthesize(self, batch: TrainingBatch
                   ) -> tuple[torch.Tensor, dict[str, tuple[torch.Tensor, torch.Tensor]]]:
        """The code ``Z-A`` and the four synthetic batches of Fig. 5.

        Returns
        -------
        code : Tensor, shape (N, code_dim)
            ``En(x | a)``.
        fakes : dict
            ``recon`` (R-A), ``trans`` (R-B), ``gen_a`` (G-A), ``gen_b`` (G-B): each a pair
            (frames ``(N, 3, S, S)``, labels ``(N,)``), differentiable w.r.t. En and De.
        """
        a, b = batch.condition, batch.target
        z = self.encoder(batch.x, self.one_hot(a))
        return z, {
            "recon": (self.decode(z, a), a),
            "trans": (self.decode(z, b), b),
            "gen_a": (self.decode(batch.noise, a), a),
            "gen_b": (self.decode(batch.noise, b), b),
        }

    def c_step(self, batch: TrainingBatch, optimizer: torch.optim.Optimizer) -> dict[str, float]:
        """Cross-entropy update of ``C`` on the weather labels."""
        optimizer.zero_grad(set_to_none=True)
        logits = self.classifier(batch.x)
        loss = F.cross_entropy(logits, batch.condition)
        loss.backward()
        optimizer.step()
        acc = (logits.argmax(dim=1) == batch.condition).float().mean()
        return {"C/loss": loss.item(), "C/acc": acc.item()}

    def d_step(self, batch: TrainingBatch, fakes: Mapping[str, tuple[torch.Tensor, torch.Tensor]],
               optimizer: torch.optim.Optimizer) -> dict[str, float]:
        """Update ``D``: real frames under their condition vs the synthetic batches."""
        optimizer.zero_grad(set_to_none=True)
        real = batch.x.detach().requires_grad_(True) if self.r1_gamma > 0 else batch.x
        real_logits = self.discriminator(real, self.one_hot(batch.condition))
        loss_real = self.critic_loss(real_logits, real=True)
        logs = {"D/real": torch.sigmoid(real_logits).mean().item()}
        if self.r1_gamma > 0:
            r1 = r1_penalty(real_logits, real)
            loss_real = loss_real + 0.5 * self.r1_gamma * r1
            logs["D/r1"] = r1.item()
        loss_fake = torch.zeros((), device=batch.x.device)
        fake_scores = []
        for key, (frames, condition) in fakes.items():
            logits = self.discriminator(frames.detach(), self.one_hot(condition))
            loss_fake = loss_fake + 0.5 * self.critic_loss(logits, real=False)
            score = torch.sigmoid(logits).mean().item()
            logs[f"D/{key}"] = score
            fake_scores.append(score)
        loss = loss_real + loss_fake
        loss.backward()
        optimizer.step()
        logs.update({"D/loss": loss.item(), "D/loss_real": loss_real.item(),
                     "D/loss_fake": loss_fake.item(), "D/fake": float(np.mean(fake_scores))})
        return logs

    def dz_step(self, batch: TrainingBatch, code: torch.Tensor,
                optimizer: torch.optim.Optimizer) -> dict[str, float]:
        """Update ``D_z``: prior draws ``batch.noise`` are real, codes ``En(x|a)`` fake, both
        under the frame's condition ``a`` (the prior does not depend on it).

        One forward of the concatenation (one spectral-norm power iteration per step).
        """
        if self.code_discriminator is None:
            raise ValueError("dz_step: needs loss_weights.prior > 0")
        optimizer.zero_grad(set_to_none=True)
        n = len(code)
        condition = self.one_hot(batch.condition)
        logits = self.code_discriminator(torch.cat([batch.noise, code.detach()]),
                                         torch.cat([condition, condition]))
        loss_real = gan_loss(logits[:n], real=True)
        loss_fake = gan_loss(logits[n:], real=False)
        loss = loss_real + loss_fake
        loss.backward()
        optimizer.step()
        scores = torch.sigmoid(logits.detach())
        return {"Dz/loss": loss.item(), "Dz/real": scores[:n].mean().item(),
                "Dz/fake": scores[n:].mean().item()}

    def adversary_step(self, batch: TrainingBatch, code: torch.Tensor,
                       optimizer: torch.optim.Optimizer) -> dict[str, float]:
        """Update the latent adversary ``A``: cross-entropy of the weather label from the
        detached codes. ``A/acc`` is its batch accuracy before the update (chance:
        ``1 / n_conditions``)."""
        if self.adversary is None:
            raise ValueError("adversary_step: needs loss_weights.adversary > 0")
        optimizer.zero_grad(set_to_none=True)
        logits = self.adversary(code.detach())
        loss = F.cross_entropy(logits, batch.condition)
        loss.backward()
        optimizer.step()
        acc = (logits.argmax(dim=1) == batch.condition).float().mean()
        return {"A/loss": loss.item(), "A/acc": acc.item()}

    def g_step(self, batch: TrainingBatch, fakes: Mapping[str, tuple[torch.Tensor, torch.Tensor]],
               optimizer: torch.optim.Optimizer, *, code: torch.Tensor | None = None
               ) -> dict[str, float]:
        """Update ``En`` and ``De``: fool ``D`` on every synthetic batch, reconstruct ``x``.

        With ``loss_weights.latent > 0`` (not in the paper; 0 by default) the translated frame
        ``R-B`` is encoded under ``b`` and pulled towards the (fixed) code ``Z-A``:
        ``latent * ||En(R-B | b) - Z-A||^2``, which asks the encoder for the same code of one
        scene under two weathers.

        With ``loss_weights.prior > 0`` the encoder also fools ``D_z`` (non-saturating,
        ``E/prior = -log D_z(En(x|a) | a)``), pulling the codes of every condition to the
        prior (eq. 7); with ``prior_divergence: mmd`` there is no ``D_z`` and ``E/prior`` is
        :func:`mmd_to_prior` of the codes and the batch's prior draws instead.

        With ``loss_weights.adversary > 0`` the encoder makes the latent adversary's
        prediction uniform: ``E/adversary = KL(U || A(z)) = -1/K sum_k log p_A(k|z) - log K``
        (a confusion loss, Tzeng et al. 2015; Alvi et al. 2018). Chosen over gradient reversal
        (maximising ``A``'s cross-entropy) for stability: that objective is unbounded and is
        maximised just as well by making ``A`` confidently *wrong* (swapping the weather
        clusters), which keeps the weather in the code and makes the two players chase each
        other; the confusion loss is bounded below by 0, reaches it only where ``A`` cannot
        tell the weathers apart, and its gradient vanishes there.

        ``code`` (``Z-A`` from :meth:`synthesize`, with its graph) is required when any of these
        three weights is positive.
        """
        self._require_code(code)
        frozen = self._critics()
        optimizer.zero_grad(set_to_none=True)
        for module in frozen:
            set_requires_grad(module, False)
        try:
            adv, logs = self._fool_discriminator(fakes, device=batch.x.device)
            recon = F.mse_loss(fakes["recon"][0], batch.x)
            loss = self.weights["adv"] * adv + self.weights["recon"] * recon
            loss = self._add_code_losses(loss, batch, fakes, code, logs)
            loss.backward()
            optimizer.step()
        finally:
            for module in frozen:
                set_requires_grad(module, True)
        logs.update({"G/adv": adv.item(), "G/loss": loss.item(), "E/recon": recon.item()})
        if code is not None:
            logs["E/code_norm"] = code.detach().norm(dim=1).mean().item()
        return logs

    def critic_loss(self, logits: torch.Tensor, *, real: bool) -> torch.Tensor:
        """D's loss on logits ``(N,)``: the paper's log loss (:func:`gan_loss`), or with
        ``adversarial_loss: hinge`` ``mean(relu(1 - l))`` on real and ``mean(relu(1 + l))`` on
        synthetic frames."""
        if self.adversarial_loss == "hinge":
            return F.relu(1.0 - logits).mean() if real else F.relu(1.0 + logits).mean()
        return gan_loss(logits, real=real)

    def fooling_loss(self, logits: torch.Tensor) -> torch.Tensor:
        """En/De's adversarial term on D's logits ``(N,)`` for synthetic frames: the
        non-saturating ``-log D`` (:func:`gan_loss`), or ``-mean(l)`` with hinge."""
        if self.adversarial_loss == "hinge":
            return -logits.mean()
        return gan_loss(logits, real=True)

    def _critics(self) -> list[torch.nn.Module]:
        """The critics that exist (``D``, then ``D_z`` and ``A`` when built), frozen by g_step."""
        return [m for m in (self.discriminator, self.code_discriminator, self.adversary)
                if m is not None]

    def _require_code(self, code: torch.Tensor | None) -> None:
        """Refuse a missing ``code`` when the latent, prior or adversary weight is positive."""
        needs_code = self._place_rule is not None or any(
            self.weights[k] > 0 for k in ("latent", "prior", "adversary"))
        if needs_code and code is None:
            raise ValueError("code: needed when loss_weights.latent, prior, adversary or place "
                             "> 0")

    def _fool_discriminator(self, fakes: Mapping[str, tuple[torch.Tensor, torch.Tensor]], *,
                            device: torch.device) -> tuple[torch.Tensor, dict[str, float]]:
        """``(adv, logs)``: the scalar sum over ``fakes`` of ``0.5 * -log D(frames | condition)``
        (frames (B, 3, S, S), condition (B,)), each term logged as ``G/adv_<key>``."""
        logs = {}
        adv = torch.zeros((), device=device)
        for key, (frames, condition) in fakes.items():
            term = 0.5 * self.fooling_loss(self.discriminator(frames, self.one_hot(condition)))
            logs[f"G/adv_{key}"] = term.item()
            adv = adv + term
        return adv, logs

    def _add_code_losses(self, loss: torch.Tensor, batch: TrainingBatch,
                         fakes: Mapping[str, tuple[torch.Tensor, torch.Tensor]],
                         code: torch.Tensor | None, logs: dict[str, float]) -> torch.Tensor:
        """``loss`` plus the weighted latent, prior and adversary terms on ``code`` (B, code_dim)
        that are on, in that order; each logged into ``logs`` (``E/latent``, ``E/prior``,
        ``E/adversary``)."""
        weights = self.weights
        if weights["latent"] > 0:
            trans, b = fakes["trans"]
            latent = F.mse_loss(self.encoder(trans, self.one_hot(b)), code.detach())
            loss = loss + weights["latent"] * latent
            logs["E/latent"] = latent.item()
        if weights["prior"] > 0:
            prior = (mmd_to_prior(code, batch.noise, batch.condition, prior_std=self.prior_std)
                     if self.prior_divergence == "mmd" else
                     gan_loss(self.code_discriminator(code, self.one_hot(batch.condition)),
                              real=True))
            loss = loss + weights["prior"] * prior
            logs["E/prior"] = prior.item()
        if weights["adversary"] > 0:
            log_p = self.adversary(code).log_softmax(dim=1)
            confusion = (-log_p.mean(dim=1)).mean() - math.log(self.n_conditions)
            loss = loss + weights["adversary"] * confusion
            logs["E/adversary"] = confusion.item()
        if self._place_rule is not None:
            place = self.place_loss(batch, code)
            loss = loss + weights["place"] * place
            logs["E/place"] = place.item()
        return loss

    def place_loss(self, batch: TrainingBatch, code: torch.Tensor) -> torch.Tensor:
        """InfoNCE between ``code`` = ``En(x | a)`` (B, code_dim) and ``En(positive | its
        condition)`` over the frames that have a positive (:func:`~.places.info_nce`); zero
        when fewer than two have one."""
        if batch.positive is None or batch.has_positive is None:
            raise ValueError("batch: the place term needs TrainingBatch.positive (the training "
                             "loop draws it for a model with a place rule)")
        keep = batch.has_positive
        if int(keep.sum()) < 2:  # no negative in the batch: no term this iteration
            return code.sum() * 0.0
        positive = self.encoder(batch.positive[keep], self.one_hot(batch.positive_condition[keep]))
        return info_nce(code[keep], positive, temperature=self._place_rule.temperature)

    def training_step(self, batch: TrainingBatch, optimizers: Mapping[str, torch.optim.Optimizer],
                      *, diagnostics: bool = False) -> dict[str, float]:
        """``c_step``, then one forward of En/De shared by ``d_step``, ``dz_step`` and
        ``adversary_step`` (when on; ``code_critic_steps`` updates each, on the same detached
        codes) and ``g_step``. The critic logs are those of the last critic update."""
        logs = self.c_step(batch, optimizers["C"])
        code, fakes = self.synthesize(batch)
        logs.update(self.d_step(batch, fakes, optimizers["D"]))
        for step in range(self.code_critic_steps):
            # Extra critic steps see fresh prior draws from the global CPU generator (saved in
            # checkpoints, so a resumed run draws the same); the first uses ``batch.noise``.
            critic_batch = batch if step == 0 else replace(
                batch, noise=(torch.randn(batch.noise.shape) * self.prior_std).to(code.device))
            if self.code_discriminator is not None:
                logs.update(self.dz_step(critic_batch, code, optimizers["Dz"]))
            if self.adversary is not None:
                logs.update(self.adversary_step(critic_batch, code, optimizers["A"]))
        logs.update(self.g_step(batch, fakes, optimizers["G"], code=code))
        if self.encoder_ema is not None:
            self.encoder_ema.update_parameters(self.encoder)
        return logs

    @torch.no_grad()
    def heldout_metrics(self, x: torch.Tensor, condition: torch.Tensor) -> dict[str, float]:
        """``C/acc_heldout``, ``E/recon_heldout`` (L2 reconstruction under the true label) and
        ``E/code_norm_heldout`` (mean ``||En(x|a)||``; a prior draw has norm about
        ``prior_std * sqrt(code_dim)``)."""
        was_training = self.training
        self.eval()
        try:
            acc = (self.classifier(x).argmax(dim=1) == condition).float().mean().item()
            z = self.encoder(x, self.one_hot(condition))
            mse = F.mse_loss(self.decode(z, condition), x).item()
        finally:
            self.train(was_training)
        return {"C/acc_heldout": acc, "E/recon_heldout": mse,
                "E/code_norm_heldout": z.norm(dim=1).mean().item()}

    @torch.no_grad()
    def sample_rows(self, x: torch.Tensor, condition: torch.Tensor,
                    noise: torch.Tensor) -> list[torch.Tensor]:
        """Rows: real frames; ``De(En(x|a)|k)`` for every condition k; ``De(n|k)`` for every k."""
        was_training = self.training
        self.eval()
        try:
            z = self.encoder(x, self.one_hot(condition))
            rows = [x]
            for k in range(self.n_conditions):
                rows.append(self.decode(z, torch.full_like(condition, k)))
            for k in range(self.n_conditions):
                rows.append(self.decode(noise, torch.full_like(condition, k)))
        finally:
            self.train(was_training)
        return rows


class CMALPlace(CMAL):
    """CMAL trained with place supervision (an extension, model ``cmal_place``): CMAL's
    objective plus ``loss_weights.place`` (> 0) times the place InfoNCE term on ``En``'s codes
    (:meth:`CMAL.place_loss`); the ``place`` node says which frames are the same place."""

    name = CmalPlaceConfig.name

    def __init__(self, config: CmalPlaceConfig, *, image_size: int, n_conditions: int):
        super().__init__(config, image_size=image_size, n_conditions=n_conditions)


class PlaceEncoder(CMAL):
    """The ablation of :class:`CMALPlace` without the GAN (model ``place_encoder``): CMAL's
    classifier ``C`` and encoder ``En(x | c)``, same networks and initial weights, trained with
    the place term alone (no decoder, discriminator or code critics). Encodes like CMAL,
    ``En(x | C(x))``."""

    name = PlaceEncoderConfig.name

    def __init__(self, config: PlaceEncoderConfig, *, image_size: int, n_conditions: int):
        GANModel.__init__(self, config, image_size=image_size, n_conditions=n_conditions)
        self.encoder_ema = None  # En itself encodes (no recipe switches in the ablation)
        self._place_rule = config.place
        self._build_classifier_and_encoder(config)

    @property
    def label(self) -> str:
        return "place encoder (ablation: place term alone, no GAN)"

    def make_optimizers(self) -> dict[str, torch.optim.Optimizer]:
        """``C`` (``lr_c``) and ``E`` (the encoder, ``lr_g``)."""
        opt = self.config.optimizer
        return {"C": adam(self.classifier.parameters(), opt, lr=opt.lr_c),
                "E": adam(self.encoder.parameters(), opt, lr=opt.lr_g)}

    def training_step(self, batch: TrainingBatch, optimizers: Mapping[str, torch.optim.Optimizer],
                      *, diagnostics: bool = False) -> dict[str, float]:
        """``c_step``, then one update of ``En`` on the place term (``E/place``)."""
        logs = self.c_step(batch, optimizers["C"])
        optimizer = optimizers["E"]
        optimizer.zero_grad(set_to_none=True)
        code = self.encoder(batch.x, self.one_hot(batch.condition))
        loss = self.place_loss(batch, code)
        loss.backward()
        optimizer.step()
        logs.update({"E/place": loss.item(), "E/code_norm": code.detach().norm(dim=1).mean().item()})
        return logs

    @torch.no_grad()
    def heldout_metrics(self, x: torch.Tensor, condition: torch.Tensor) -> dict[str, float]:
        """``C/acc_heldout`` and ``E/code_norm_heldout`` (no decoder: no reconstruction)."""
        was_training = self.training
        self.eval()
        try:
            acc = (self.classifier(x).argmax(dim=1) == condition).float().mean().item()
            z = self.encoder(x, self.one_hot(condition))
        finally:
            self.train(was_training)
        return {"C/acc_heldout": acc, "E/code_norm_heldout": z.norm(dim=1).mean().item()}

    @torch.no_grad()
    def sample_rows(self, x: torch.Tensor, condition: torch.Tensor,
                    noise: torch.Tensor) -> list[torch.Tensor]:
        """The real frames only (there is no decoder to draw from)."""
        return [x]


def _batched_tensors(model: GANModel, images: np.ndarray, batch_size: int):
    for start in range(0, len(images), batch_size):
        chunk = preprocess(images[start:start + batch_size], image_size=model.image_size)
        yield start, chunk.to(model.device)


@torch.no_grad()
def reconstruct_and_translate(model: CMAL, images: np.ndarray, cond_a, cond_b, *,
                              batch_size: int = 64) -> dict[str, np.ndarray]:
    """Paper Fig. 11: reconstruct frames of domain A under A and translate them into B.

    Which frames and pairs the report shows: :mod:`cmal_lcd.reports.reconstructions`.

    Parameters
    ----------
    model : CMAL
    images : ndarray, uint8, shape (n, H, W, 3)
        Frames of domain A.
    cond_a, cond_b : int or array-like of int, shape (n,)
        Condition index of each frame (A) and the condition to translate into (B).
    batch_size : int

    Returns
    -------
    dict of ndarray, uint8, shape (n, S, S, 3)
        ``a`` (the input at the model's size), ``recon_a`` = ``De(En(a|A)|A)`` and
        ``translated_b`` = ``De(En(a|A)|B)`` from the same code.
    """
    images = np.asarray(images)
    n = len(images)
    cond_a = np.array(np.broadcast_to(np.asarray(cond_a, dtype=np.int64), (n,)))
    cond_b = np.array(np.broadcast_to(np.asarray(cond_b, dtype=np.int64), (n,)))
    for name, cond in (("cond_a", cond_a), ("cond_b", cond_b)):
        if n and (cond.min() < 0 or cond.max() >= model.n_conditions):
            raise ValueError(f"{name}: condition indices must be in [0, {model.n_conditions})")
    was_training = model.training
    model.eval()
    out = {"a": [], "recon_a": [], "translated_b": []}
    try:
        for start, x in _batched_tensors(model, images, batch_size):
            a = torch.from_numpy(np.ascontiguousarray(cond_a[start:start + len(x)])).to(x.device)
            b = torch.from_numpy(np.ascontiguousarray(cond_b[start:start + len(x)])).to(x.device)
            z = model.encoder(x, model.one_hot(a))
            out["a"].append(to_uint8(x))
            out["recon_a"].append(to_uint8(model.decode(z, a)))
            out["translated_b"].append(to_uint8(model.decode(z, b)))
    finally:
        model.train(was_training)
    size = model.image_size
    return {k: (np.concatenate(v) if v else np.zeros((0, size, size, 3), np.uint8))
            for k, v in out.items()}


@torch.no_grad()
def predict_conditions(model: CMAL, images: np.ndarray, *, batch_size: int = 256) -> np.ndarray:
    """The classifier's decision for each frame.

    Parameters
    ----------
    images : ndarray, uint8, shape (N, H, W, 3)

    Returns
    -------
    ndarray, int64, shape (N,)
    """
    was_training = model.training
    model.eval()
    try:
        preds = [model.classify(x).argmax(dim=1).cpu().numpy()
                 for _, x in _batched_tensors(model, np.asarray(images), batch_size)]
    finally:
        model.train(was_training)
    return np.concatenate(preds).astype(np.int64) if preds else np.zeros(0, np.int64)


def condition_accuracy(model: CMAL, images: np.ndarray, labels: np.ndarray, *,
                       batch_size: int = 256) -> float:
    """Fraction of frames whose weather the classifier ``C`` gets right.

    Parameters
    ----------
    model : CMAL
    images : ndarray, uint8, shape (N, H, W, 3)
    labels : ndarray, int, shape (N,)
        Condition index of each frame (position in ``dataset.json["conditions"]``).

    Returns
    -------
    float
        Accuracy in ``[0, 1]``.
    """
    labels = np.asarray(labels)
    if labels.shape != (len(images),):
        raise ValueError(f"labels: expected shape ({len(images)},), got {labels.shape}")
    if len(labels) == 0:
        raise ValueError("images: expected at least one frame")
    return float(np.mean(predict_conditions(model, images, batch_size=batch_size) == labels))
