"""The objective's directions and the condition each network receives (issue 16, item 1).

Every expected value here is computed independently of the step under test: the losses from
``-log sigmoid`` / ``-log(1 - sigmoid)`` written out, the scores by calling the (frozen,
eval-mode) discriminator before and after the step. So a term with the wrong target (the
generator helping ``D``) or a network fed the wrong condition fails here, whatever the logs say.

Which deliberate bug each test catches is recorded in ``docs/testing.md``.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from model_helpers import tiny_config, weather_frames

from cmal_lcd.models import build_model, preprocess
from cmal_lcd.models.base import TrainingBatch, gan_loss

STEPS = 4  # updates on the same batch: enough for the direction to show at these learning rates
LR = 1e-3


# ---------------------------------------------------------------------------- helpers
def cmal(**weights):
    cfg = tiny_config("cmal", loss_weights={"adv": 1.0, "recon": 0.0, **weights},
                      optimizer={"lr_d": LR, "lr_g": LR, "lr_c": LR})
    return build_model("cmal", cfg, image_size=16, n_conditions=3, seed=0)


def bigan(**overrides):
    cfg = tiny_config("bigan", discriminator_dropout=0.0,
                      optimizer={"lr_d": LR, "lr_g": LR, "lr_e": LR}, **overrides)
    return build_model("bigan", cfg, image_size=16, n_conditions=3, seed=0)


def fixed_batch(model, n=12) -> TrainingBatch:
    """Frames of conditions a = 0, 1, 2, ...; targets b = a + 1 (never a); fixed noise."""
    images, labels = weather_frames(n)
    a = torch.from_numpy(labels)
    b = (a + 1) % 3
    noise = torch.randn(n, model.code_dim, generator=torch.Generator().manual_seed(1))
    return TrainingBatch(x=preprocess(images, image_size=16), condition=a, target=b,
                         noise=noise * model.prior_std)


def minus_log_sigmoid(logits):
    """-log D, written out (not via gan_loss)."""
    return -torch.log(torch.sigmoid(logits.double())).mean().item()


def minus_log_one_minus_sigmoid(logits):
    """-log(1 - D), written out."""
    return -torch.log(1 - torch.sigmoid(logits.double())).mean().item()


class frozen_eval:
    """Evaluate a discriminator without updating it (no spectral-norm power iteration)."""

    def __init__(self, module):
        self.module = module

    def __enter__(self):
        self.was = self.module.training
        self.module.eval()
        self.grad = torch.no_grad()
        self.grad.__enter__()
        return self.module

    def __exit__(self, *exc):
        self.grad.__exit__(*exc)
        self.module.train(self.was)


# ---------------------------------------------------------------------------- gan_loss
def test_gan_loss_real_target_is_minus_log_sigmoid_on_hand_values():
    logits = torch.tensor([0.0, math.log(3.0), -math.log(3.0)])
    # sigmoid = 1/2, 3/4, 1/4
    expected = (math.log(2) + math.log(4 / 3) + math.log(4)) / 3
    assert gan_loss(logits, real=True).item() == pytest.approx(expected, rel=1e-6)


def test_gan_loss_fake_target_is_minus_log_one_minus_sigmoid_on_hand_values():
    logits = torch.tensor([0.0, math.log(3.0), -math.log(3.0)])
    # 1 - sigmoid = 1/2, 1/4, 3/4
    expected = (math.log(2) + math.log(4) + math.log(4 / 3)) / 3
    assert gan_loss(logits, real=False).item() == pytest.approx(expected, rel=1e-6)


def test_gan_loss_is_finite_and_linear_for_confidently_wrong_logits():
    logits = torch.tensor([200.0, -200.0])
    # real target: -log sigmoid(200) ~ 0, -log sigmoid(-200) ~ 200 -> mean 100
    assert gan_loss(logits, real=True).item() == pytest.approx(100.0, rel=1e-6)
    assert gan_loss(logits, real=False).item() == pytest.approx(100.0, rel=1e-6)
    assert gan_loss(torch.tensor([200.0]), real=False).item() == pytest.approx(200.0)
    assert gan_loss(torch.tensor([200.0]), real=True).item() == pytest.approx(0.0, abs=1e-6)


# ---------------------------------------------------------------------------- CMAL signs
def cmal_d_loss(model, batch, fakes) -> float:
    """Eq. 9-10 for D, written out: -log D(x|a) - 1/2 sum_fakes log(1 - D(fake|c))."""
    with frozen_eval(model.discriminator) as d:
        loss = minus_log_sigmoid(d(batch.x, model.one_hot(batch.condition)))
        for frames, condition in fakes.values():
            loss += 0.5 * minus_log_one_minus_sigmoid(d(frames, model.one_hot(condition)))
    return loss


def cmal_fake_scores(model, batch) -> dict[str, float]:
    """Mean D(fake | its condition) of each synthetic batch (fresh fakes, D frozen)."""
    with torch.no_grad():
        _, fakes = model.synthesize(batch)
    with frozen_eval(model.discriminator) as d:
        return {k: torch.sigmoid(d(f, model.one_hot(c))).mean().item()
                for k, (f, c) in fakes.items()}


def test_cmal_d_step_lowers_the_discriminators_loss_on_a_fixed_batch():
    model = cmal()
    batch = fixed_batch(model)
    with torch.no_grad():
        _, fakes = model.synthesize(batch)
    opt = model.make_optimizers()["D"]
    before = cmal_d_loss(model, batch, fakes)
    for _ in range(STEPS):
        model.d_step(batch, fakes, opt)
    assert cmal_d_loss(model, batch, fakes) < before - 1e-3


def test_cmal_d_step_raises_real_scores_and_lowers_every_fake_score():
    model = cmal()
    batch = fixed_batch(model)
    with torch.no_grad():
        _, fakes = model.synthesize(batch)
    opt = model.make_optimizers()["D"]

    def scores():
        with frozen_eval(model.discriminator) as d:
            out = {"real": torch.sigmoid(d(batch.x, model.one_hot(batch.condition))).mean()}
            out.update({k: torch.sigmoid(d(f, model.one_hot(c))).mean()
                        for k, (f, c) in fakes.items()})
        return {k: v.item() for k, v in out.items()}

    before = scores()
    for _ in range(STEPS):
        model.d_step(batch, fakes, opt)
    after = scores()
    assert after["real"] > before["real"]
    for key in ("recon", "trans", "gen_a", "gen_b"):
        assert after[key] < before[key], key


def test_cmal_generator_step_raises_ds_score_on_every_synthetic_batch():
    """Non-saturating min over En/De: after En/De steps (D frozen) D rates the fakes higher."""
    model = cmal()
    batch = fixed_batch(model)
    opt = model.make_optimizers()["G"]
    d_before = [p.detach().clone() for p in model.discriminator.parameters()]
    before = cmal_fake_scores(model, batch)
    for _ in range(STEPS):
        _, fakes = model.synthesize(batch)
        model.g_step(batch, fakes, opt)
    after = cmal_fake_scores(model, batch)
    for key in ("recon", "trans", "gen_a", "gen_b"):
        assert after[key] > before[key], (key, before[key], after[key])
    assert all(torch.equal(p, q) for p, q in zip(model.discriminator.parameters(), d_before))


def test_cmal_generator_step_reconstruction_term_lowers_the_reconstruction_error():
    """Eq. 11's ``recon * ||x - De(En(x|a)|a)||^2`` pulls R-A towards x (adv weight 0)."""
    model = cmal(adv=0.0, recon=1.0)
    batch = fixed_batch(model)
    opt = model.make_optimizers()["G"]

    def error():
        with torch.no_grad():
            _, fakes = model.synthesize(batch)
        return ((fakes["recon"][0] - batch.x) ** 2).mean().item()

    before = error()
    for _ in range(STEPS):
        _, fakes = model.synthesize(batch)
        model.g_step(batch, fakes, opt)
    assert error() < before


def test_cmal_generator_loss_adds_the_reconstruction_with_a_positive_weight():
    """G/loss = adv * sum of the four -1/2 log D(fake) terms + recon * MSE, each recomputed."""
    model = cmal(adv=1.0, recon=3.0)
    batch = fixed_batch(model)
    opt = model.make_optimizers()["G"]
    torch.manual_seed(0)
    _, fakes = model.synthesize(batch)
    with frozen_eval(model.discriminator) as d:
        adv = sum(0.5 * minus_log_sigmoid(d(f, model.one_hot(c))) for f, c in fakes.values())
    mse = ((fakes["recon"][0].detach() - batch.x) ** 2).mean().item()
    model.discriminator.eval()  # same D forward as above (no power iteration) inside g_step
    logs = model.g_step(batch, fakes, opt)
    assert logs["G/loss"] == pytest.approx(adv + 3.0 * mse, rel=1e-4)


def test_cmal_prior_term_critic_learns_and_encoder_fools_it():
    """Eq. 7 term (off by default): D_z rates prior draws higher than codes after its steps;
    the encoder's step raises D_z's score on the codes."""
    model = cmal(adv=0.0, prior=1.0)
    batch = fixed_batch(model)
    opts = model.make_optimizers()
    dz = model.code_discriminator
    cond = model.one_hot(batch.condition)

    def code_score():
        with torch.no_grad():
            code = model.encoder(batch.x, cond)
        with frozen_eval(dz):
            return (torch.sigmoid(dz(code, cond)).mean().item(),
                    torch.sigmoid(dz(batch.noise, cond)).mean().item())

    fake0, real0 = code_score()
    code, _ = model.synthesize(batch)
    for _ in range(STEPS):
        model.dz_step(batch, code, opts["Dz"])
    fake1, real1 = code_score()
    assert fake1 < fake0 and real1 > real0
    for _ in range(STEPS):
        code, fakes = model.synthesize(batch)
        model.g_step(batch, fakes, opts["G"], code=code)
    fake2, _ = code_score()
    assert fake2 > fake1


def test_cmal_adversary_term_adversary_learns_and_encoder_confuses_it():
    """Eq. 8 term (off by default): A's cross-entropy falls after its steps; the encoder's
    step lowers the confusion loss KL(U || A(z)) (A's prediction moves towards uniform)."""
    model = cmal(adv=0.0, adversary=1.0)
    batch = fixed_batch(model)
    opts = model.make_optimizers()
    cond = model.one_hot(batch.condition)

    def adversary_view():
        with torch.no_grad():
            log_p = model.adversary(model.encoder(batch.x, cond)).log_softmax(dim=1)
        ce = -log_p[torch.arange(len(batch.condition)), batch.condition].mean().item()
        kl = ((-log_p.mean(dim=1)).mean() - math.log(3)).item()
        return ce, kl

    ce0, _ = adversary_view()
    code, _ = model.synthesize(batch)
    for _ in range(STEPS):
        model.adversary_step(batch, code, opts["A"])
    ce1, kl1 = adversary_view()
    assert ce1 < ce0
    for _ in range(STEPS):
        code, fakes = model.synthesize(batch)
        model.g_step(batch, fakes, opts["G"], code=code)
    _, kl2 = adversary_view()
    assert kl2 < kl1


def test_cmal_latent_term_pulls_the_code_of_the_translation_towards_the_source_code():
    model = cmal(adv=0.0, latent=1.0)
    batch = fixed_batch(model)
    opt = model.make_optimizers()["G"]
    a, b = model.one_hot(batch.condition), model.one_hot(batch.target)

    def gap():
        with torch.no_grad():
            z = model.encoder(batch.x, a)
            return ((model.encoder(model.decoder(z, b), b) - z) ** 2).mean().item()

    before = gap()
    for _ in range(STEPS):
        code, fakes = model.synthesize(batch)
        model.g_step(batch, fakes, opt, code=code)
    assert gap() < before


# ---------------------------------------------------------------------------- BiGAN signs
def bigan_scores(model, batch):
    """D's scores (all columns) of encoder pairs (x, E(x)) and generator pairs (G(n), n)."""
    with torch.no_grad():
        z_enc, x_gen = model.encoder(batch.x), model.generator(batch.noise)
    with frozen_eval(model.discriminator) as d:
        return d.scores(batch.x, z_enc), d.scores(x_gen, batch.noise)


def test_bigan_d_step_lowers_the_discriminators_loss_on_a_fixed_batch():
    model = bigan()
    batch = fixed_batch(model)
    with torch.no_grad():
        z_enc, x_gen = model.encoder(batch.x), model.generator(batch.noise)
    opt = model.make_optimizers()["D"]

    def loss():
        with frozen_eval(model.discriminator) as d:
            real, fake = d.scores(batch.x, z_enc), d.scores(x_gen, batch.noise)
        return sum(minus_log_sigmoid(real[:, k]) + minus_log_one_minus_sigmoid(fake[:, k])
                   for k in range(real.shape[1]))

    before = loss()
    for _ in range(STEPS):
        model.d_step(batch.x, z_enc, x_gen, batch.noise, opt)
    assert loss() < before - 1e-3


@pytest.mark.parametrize("unary", [False, True])
def test_bigan_d_step_raises_encoder_pair_scores_and_lowers_generator_pair_scores(unary):
    model = bigan(unary_scores=unary)
    batch = fixed_batch(model)
    with torch.no_grad():
        z_enc, x_gen = model.encoder(batch.x), model.generator(batch.noise)
    opt = model.make_optimizers()["D"]
    enc0, gen0 = bigan_scores(model, batch)
    for _ in range(STEPS):
        model.d_step(batch.x, z_enc, x_gen, batch.noise, opt)
    enc1, gen1 = bigan_scores(model, batch)
    assert enc0.shape[1] == (3 if unary else 1)
    for k in range(enc0.shape[1]):
        assert torch.sigmoid(enc1[:, k]).mean() > torch.sigmoid(enc0[:, k]).mean(), k
        assert torch.sigmoid(gen1[:, k]).mean() < torch.sigmoid(gen0[:, k]).mean(), k


@pytest.mark.parametrize("unary", [False, True])
def test_bigan_generator_step_swaps_the_labels_d_would_give(unary):
    """E and G fool D: D's joint score of generator pairs rises, of encoder pairs falls; with
    unary scores, the frame score of G(n) rises and the code score of E(x) falls."""
    model = bigan(unary_scores=unary)
    batch = fixed_batch(model)
    opt = model.make_optimizers()["G"]
    enc0, gen0 = bigan_scores(model, batch)
    for _ in range(STEPS):
        model.g_step(batch.x, model.encoder(batch.x), model.generator(batch.noise),
                     batch.noise, opt)
    enc1, gen1 = bigan_scores(model, batch)
    mean = lambda s, k: torch.sigmoid(s[:, k]).mean().item()  # noqa: E731
    assert mean(gen1, 0) > mean(gen0, 0)
    assert mean(enc1, 0) < mean(enc0, 0)
    if unary:
        assert mean(gen1, 1) > mean(gen0, 1)  # frame score of generated frames
        assert mean(enc1, 2) < mean(enc0, 2)  # code score of encoder codes


# ---------------------------------------------------------------------------- conditions
class Recorder:
    """Forward hooks that record each call's inputs and output of a module."""

    def __init__(self, module):
        self.calls: list[tuple[tuple, torch.Tensor]] = []
        self.handle = module.register_forward_hook(
            lambda _m, args, out: self.calls.append((tuple(a.detach() for a in args),
                                                     out.detach())))


def label_of(one_hot: torch.Tensor) -> torch.Tensor:
    assert torch.all((one_hot == 0) | (one_hot == 1)) and torch.all(one_hot.sum(dim=1) == 1)
    return one_hot.argmax(dim=1)


@pytest.mark.parametrize("weights", [{}, {"latent": 1.0, "prior": 1.0, "adversary": 1.0}],
                         ids=["paper", "all-terms"])
def test_cmal_training_step_gives_each_network_the_condition_of_its_branch(weights):
    """En(x | a); De(z|a), De(z|b), De(n|a), De(n|b); D(x|a) and D(fake | the condition it was
    made for) in both the D and the En/De step; with the latent term En(R-B | b)."""
    model = cmal(recon=1.0, **weights)
    batch = fixed_batch(model)
    a, b = batch.condition, batch.target
    assert torch.all(a != b)
    enc, dec, disc = (Recorder(model.encoder), Recorder(model.decoder),
                      Recorder(model.discriminator))
    dz = Recorder(model.code_discriminator) if model.code_discriminator is not None else None
    model.training_step(batch, model.make_optimizers())

    # encoder: the real frames under the SOURCE condition a (then R-B under b for the latent term)
    (x_in, c_in), z = enc.calls[0]
    assert torch.equal(x_in, batch.x) and torch.equal(label_of(c_in), a)
    if weights:
        assert len(enc.calls) == 2
        (x_in, c_in), _ = enc.calls[1]
        assert torch.equal(label_of(c_in), b)
    else:
        assert len(enc.calls) == 1

    # decoder: code under a and b, noise under a and b
    assert len(dec.calls) == 4
    made = {}
    for (z_in, c_in), out in dec.calls:
        source = "code" if torch.equal(z_in, z) else "noise" if torch.equal(z_in, batch.noise) \
            else None
        cond = "a" if torch.equal(label_of(c_in), a) else "b" if torch.equal(label_of(c_in), b) \
            else None
        made[(source, cond)] = out
    assert set(made) == {("code", "a"), ("code", "b"), ("noise", "a"), ("noise", "b")}
    if weights:
        assert torch.equal(enc.calls[1][0][0], made[("code", "b")])  # En(R-B | b)

    # discriminator: d_step sees x|a and 4 fakes, g_step the same 4 fakes again
    expected = {("real", "a"), *[(k, c) for k, c in made]}
    seen = []
    for (x_in, c_in), _ in disc.calls:
        lab = label_of(c_in)
        if torch.equal(x_in, batch.x):
            source = ("real",)
        else:
            source = tuple(k for k, out in made.items() if torch.equal(x_in, out))
            assert len(source) == 1, "D scored a frame that is neither real nor a synthetic batch"
            source = source[0]
        cond = "a" if torch.equal(lab, a) else "b" if torch.equal(lab, b) else None
        if source == ("real",):
            seen.append(("real", cond))
        else:
            assert source[1] == cond, f"D scored {source} under condition {cond}"
            seen.append(source)
    assert set(seen) == expected
    assert seen.count(("real", "a")) == 1 and len(seen) == 9

    # code discriminator: prior draws and codes, both under a
    if dz is not None:
        for (z_in, c_in), _ in dz.calls:
            assert torch.equal(label_of(c_in), torch.cat([a, a])[:len(c_in)])


def test_cmal_heldout_metrics_and_reconstruction_figure_encode_under_the_source_condition():
    from cmal_lcd.models.cmal import reconstruct_and_translate
    model = cmal()
    batch = fixed_batch(model)
    enc, dec = Recorder(model.encoder), Recorder(model.decoder)
    model.heldout_metrics(batch.x, batch.condition)
    assert torch.equal(label_of(enc.calls[-1][0][1]), batch.condition)
    assert torch.equal(label_of(dec.calls[-1][0][1]), batch.condition)
    images, labels = weather_frames(6)
    reconstruct_and_translate(model, images, labels, (labels + 1) % 3)
    assert torch.equal(label_of(enc.calls[-1][0][1]), torch.from_numpy(labels))
    assert [label_of(c[0][1]).tolist() for c in dec.calls[-2:]] == [
        labels.tolist(), ((labels + 1) % 3).tolist()]


def test_cmal_encode_uses_the_classifiers_decision_not_a_label():
    """At matching time there is no label: En(x | onehot(argmax C(x)))."""
    model = cmal()
    batch = fixed_batch(model)
    with torch.no_grad():
        model.classifier.head.bias.copy_(torch.tensor([0.0, 0.0, 1e3]))  # C says "2"
    enc = Recorder(model.encoder)
    with torch.no_grad():
        model.encode(batch.x)
    assert torch.all(label_of(enc.calls[0][0][1]) == 2)


def test_bigan_training_step_pairs_frames_with_their_own_codes():
    """D(x, E(x)) and D(G(n), n): E sees the real frames, G the noise, D each pair unmixed."""
    model = bigan()
    batch = fixed_batch(model)
    enc, gen = Recorder(model.encoder), Recorder(model.generator)
    pairs = []
    scores = model.discriminator.scores

    def recording_scores(x, z):
        pairs.append((x.detach(), z.detach()))
        return scores(x, z)

    model.discriminator.scores = recording_scores
    model.training_step(batch, model.make_optimizers())
    (x_in,), z_enc = enc.calls[0]
    (n_in,), x_gen = gen.calls[0]
    assert torch.equal(x_in, batch.x) and torch.equal(n_in, batch.noise)
    kinds = []
    for x, z in pairs:
        if torch.equal(x, batch.x) and torch.equal(z, z_enc):
            kinds.append("encoder")
        elif torch.equal(x, x_gen) and torch.equal(z, batch.noise):
            kinds.append("generator")
        else:
            kinds.append("mixed")
    assert kinds == ["encoder", "generator", "encoder", "generator"]


def test_fixed_batch_has_distinct_source_and_target_conditions():
    batch = fixed_batch(cmal())
    assert np.all(batch.condition.numpy() != batch.target.numpy())
