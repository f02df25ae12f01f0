"""CMAL's optional code terms (eq. 7): the prior discriminator D_z(z|c), the latent weather
adversary A(z), the prior scale ``prior_std``; weights 0 are the paper's objective."""

import math
from dataclasses import replace

import numpy as np
import pytest
import torch
from model_helpers import CONDITIONS, tiny_config, weather_frames

from cmal_lcd.models import build_model, load_trained, preprocess, train_model
from cmal_lcd.models.base import TrainingBatch
from cmal_lcd.models.cmal import CMAL
from cmal_lcd.models.config import model_config
from cmal_lcd.models.training import seeded_noise


def make_model(**overrides) -> CMAL:
    return build_model("cmal", tiny_config("cmal", **overrides), image_size=16, n_conditions=3,
                       seed=0)


def make_batch(model: CMAL, n: int = 24, *, seed: int = 0) -> TrainingBatch:
    images, labels = weather_frames(n, seed=seed)
    target = (labels + 1) % 3
    noise = seeded_noise(n, model.code_dim, seed=seed, std=model.prior_std)
    return TrainingBatch(x=preprocess(images, image_size=16), condition=torch.from_numpy(labels),
                         target=torch.from_numpy(target), noise=noise)


def distance_to_prior(code: torch.Tensor, prior_std: float) -> float:
    """Squared 2-Wasserstein distance of the codes' diagonal Gaussian fit to N(0, s^2 I)."""
    code = code.detach()
    return float((code.mean(0) ** 2).sum() + ((code.std(0) - prior_std) ** 2).sum())


def entropy(logits: torch.Tensor) -> float:
    log_p = logits.log_softmax(dim=1)
    return float(-(log_p.exp() * log_p).sum(dim=1).mean())


def true_probability(logits: torch.Tensor, label: torch.Tensor) -> float:
    return float(logits.softmax(dim=1).gather(1, label[:, None]).mean())


# ---------------------------------------------------------------- the paper objective


def test_zero_weights_build_no_extra_module_and_train_exactly_as_the_paper_objective():
    cfg = tiny_config("cmal")  # conf/objective/paper.yaml: prior and adversary weights 0
    assert cfg["loss_weights"]["latent"] == 0
    paper = build_model("cmal", cfg, image_size=16, n_conditions=3, seed=0)
    assert paper.code_discriminator is None and paper.adversary is None
    assert set(paper.make_optimizers()) == {"C", "D", "G"}
    assert not any(k.startswith(("code_discriminator.", "adversary."))
                   for k in paper.state_dict())
    batch = make_batch(paper, 8)
    logs = {"paper": paper.training_step(batch, paper.make_optimizers())}
    assert not any(k.startswith(("Dz/", "A/")) or k in ("E/prior", "E/adversary")
                   for k in logs["paper"])
    weights = cfg["loss_weights"]
    assert logs["paper"]["G/loss"] == pytest.approx(
        weights["adv"] * logs["paper"]["G/adv"] + weights["recon"] * logs["paper"]["E/recon"],
        rel=1e-5)


def test_the_extra_modules_do_not_change_the_initial_weights_of_the_paper_modules():
    paper = make_model()
    both = make_model(loss_weights={"prior": 1.0, "adversary": 1.0})
    assert set(both.make_optimizers()) == {"C", "D", "G", "Dz", "A"}
    extra = {k for k in both.state_dict() if k.startswith(("code_discriminator.", "adversary."))}
    assert extra and set(both.state_dict()) - extra == set(paper.state_dict())
    for key, value in paper.state_dict().items():
        assert torch.equal(value, both.state_dict()[key]), key


# ---------------------------------------------------------------- (a) prior discriminator


def test_the_prior_discriminator_learns_and_the_encoder_moves_codes_to_the_prior():
    # 32-d codes (the tiny encoder's 128 features can fill them; 1024-d codes of a 128-feature
    # encoder lie in a subspace no prior draw does). Initial codes: per-dimension std ~0.3 and
    # a common offset, far from N(0, I). Only the prior term trains the encoder here.
    model = make_model(code_dim=32, loss_weights={"adv": 0.0, "recon": 0.0, "prior": 1.0},
                       optimizer={"lr_d": 1e-3, "lr_g": 1e-3})
    opts = model.make_optimizers()
    batch = make_batch(model)

    def with_fresh_prior_draws(step):
        return replace(batch, noise=seeded_noise(len(batch.x), 32, seed=100 + step))

    code, _ = model.synthesize(batch)
    d_losses = [model.dz_step(with_fresh_prior_draws(i), code, opts["Dz"])["Dz/loss"]
                for i in range(20)]
    assert np.mean(d_losses[-5:]) < 0.8 * np.mean(d_losses[:5])  # it tells codes from n ~ P_Z

    before = distance_to_prior(code, 1.0)
    for step in range(30):
        code, fakes = model.synthesize(batch)
        for k in range(5):  # keep the critic ahead, as an adversarial autoencoder needs
            model.dz_step(with_fresh_prior_draws(1000 + 5 * step + k), code, opts["Dz"])
        logs = model.g_step(batch, fakes, opts["G"], code=code)
    after = distance_to_prior(model.synthesize(batch)[0], 1.0)
    # measured: 19 -> 10; with the sign flipped (the encoder helping D_z) 19 -> 78
    assert after < 0.7 * before
    assert set(logs) >= {"E/prior", "E/code_norm"} and math.isfinite(logs["E/prior"])


def test_the_prior_term_only_reaches_the_encoder_through_the_code():
    model = make_model(loss_weights={"adv": 0.0, "recon": 0.0, "prior": 1.0})
    opts = model.make_optimizers()
    batch = make_batch(model, 8)
    code, fakes = model.synthesize(batch)
    dz_before = [p.detach().clone() for p in model.code_discriminator.parameters()]
    dec_before = [p.detach().clone() for p in model.decoder.parameters()]
    model.g_step(batch, fakes, opts["G"], code=code)
    assert all(torch.equal(p, q) for p, q in zip(model.code_discriminator.parameters(), dz_before))
    assert all(torch.equal(p, q) for p, q in zip(model.decoder.parameters(), dec_before))
    assert all(p.requires_grad for p in model.code_discriminator.parameters())
    with pytest.raises(ValueError, match="code"):
        model.g_step(batch, fakes, opts["G"])


# ---------------------------------------------------------------- (b) latent adversary


def test_the_adversary_learns_the_weather_and_the_encoder_step_confuses_it():
    # The encoder sees the condition as input channels, so its codes carry the weather.
    model = make_model(loss_weights={"adv": 0.0, "recon": 0.0, "adversary": 1.0})
    opts = model.make_optimizers()
    batch = make_batch(model)
    code, _ = model.synthesize(batch)
    steps = [model.adversary_step(batch, code, opts["A"]) for _ in range(30)]
    assert steps[-1]["A/loss"] < 0.5 * steps[0]["A/loss"]
    assert steps[-1]["A/acc"] == 1.0  # 3 conditions: chance is 1/3

    with torch.no_grad():
        logits_before = model.adversary(code)
    adversary_before = [p.detach().clone() for p in model.adversary.parameters()]
    for _ in range(10):  # encoder steps only, against the trained (fixed) adversary
        code, fakes = model.synthesize(batch)
        logs = model.g_step(batch, fakes, opts["G"], code=code)
    assert all(torch.equal(p, q) for p, q in zip(model.adversary.parameters(), adversary_before))
    with torch.no_grad():
        logits = model.adversary(model.synthesize(batch)[0])
    # a flipped sign (the encoder helping A) would lower the entropy instead
    before, after = entropy(logits_before), entropy(logits)
    assert after > before + 0.3 * (math.log(3) - before)
    assert true_probability(logits, batch.condition) < true_probability(logits_before,
                                                                        batch.condition)
    assert 0.0 <= logs["E/adversary"] <= math.log(3) * 10


def test_the_confusion_loss_is_the_kl_from_uniform_and_zero_at_a_uniform_prediction():
    model = make_model(loss_weights={"adv": 0.0, "recon": 0.0, "adversary": 2.0})
    with torch.no_grad():
        for p in model.adversary.body[-1].parameters():
            p.zero_()  # A predicts uniform whatever the code
    batch = make_batch(model, 8)
    code, fakes = model.synthesize(batch)
    logs = model.g_step(batch, fakes, model.make_optimizers()["G"], code=code)
    assert logs["E/adversary"] == pytest.approx(0.0, abs=1e-6)
    assert logs["G/loss"] == pytest.approx(0.0, abs=1e-6)


def test_each_iteration_updates_the_code_critics_code_critic_steps_times():
    model = make_model(code_critic_steps=3, code_critic_hidden=16,
                       loss_weights={"prior": 1.0, "adversary": 1.0})
    opts = model.make_optimizers()
    logs = model.training_step(make_batch(model, 8), opts)
    for key in ("Dz", "A"):
        steps = {float(state["step"]) for state in opts[key].state.values()}
        assert steps == {3.0}, key
    assert {float(state["step"]) for state in opts["G"].state.values()} == {1.0}
    for key in ("Dz/loss", "Dz/real", "Dz/fake", "E/prior", "A/loss", "A/acc", "E/adversary"):
        assert math.isfinite(logs[key]), key


# ---------------------------------------------------------------- prior scale and config


def test_the_loop_draws_the_noise_from_the_prior_scale(tmp_path, monkeypatch):
    torch.testing.assert_close(seeded_noise(4, 8, seed=1, std=0.5),
                               0.5 * seeded_noise(4, 8, seed=1))
    assert torch.equal(seeded_noise(4, 8, seed=1, std=1.0), seeded_noise(4, 8, seed=1))
    seen = []
    original = CMAL.training_step

    def spy(self, batch, optimizers, **kwargs):
        seen.append(float(batch.noise.std()))
        return original(self, batch, optimizers, **kwargs)

    monkeypatch.setattr(CMAL, "training_step", spy)
    images, labels = weather_frames()
    train_model("cmal", tiny_config("cmal", prior_std=0.25, iterations=2), images, labels,
                conditions=CONDITIONS, out_dir=tmp_path, seed=0, device="cpu")
    assert len(seen) == 2 and all(0.2 < s < 0.3 for s in seen)


@pytest.mark.parametrize("overrides, message", [
    ({"loss_weights": {"priors": 1.0}}, "priors"),
    ({"loss_weights": {"adversary": -1.0}}, "adversary"),
    ({"loss_weights": {"prior": "on"}}, "prior"),
    ({"prior_std": 0.0}, "prior_std"),
    ({"prior_std": "wide"}, "prior_std"),
    ({"code_critic_steps": 0, "loss_weights": {"prior": 1.0}}, "code_critic_steps"),
])
def test_bad_code_term_settings_are_named(overrides, message):
    with pytest.raises(ValueError, match=message):
        make_model(**overrides)


def test_the_key_check_knows_the_new_keys_and_still_refuses_typos():
    model_config("cmal", tiny_config("cmal", prior_std=0.5, code_critic_hidden=8))
    with pytest.raises(ValueError, match=r"^models\.cmal\.prior_sd: unknown key"):
        model_config("cmal", tiny_config("cmal", prior_sd=0.5))


# ---------------------------------------------------------------- checkpoints


def test_a_killed_run_with_the_code_terms_resumes_to_the_same_weights(tmp_path):
    # two critic steps per iteration: the second draws prior codes from the global torch RNG,
    # which the checkpoint must restore for the resumed run to draw the same
    cfg = tiny_config("cmal", iterations=6, code_critic_hidden=16, code_critic_steps=2,
                      loss_weights={"prior": 1.0, "adversary": 1.0})
    images, labels = weather_frames()

    def run(out, callback=None):
        return train_model("cmal", cfg, images, labels, conditions=CONDITIONS, out_dir=out,
                           seed=0, device="cpu", callback=callback)

    reference = run(tmp_path / "ref")

    def die(iteration, logs):
        if iteration == 5:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run(tmp_path / "run", die)
    checkpoint = torch.load(tmp_path / "run" / "checkpoints" / "last.pt", weights_only=True)
    assert checkpoint["iteration"] == 4 and set(checkpoint["optimizers"]) >= {"Dz", "A"}
    assert checkpoint["optimizers"]["Dz"]["state"] and checkpoint["optimizers"]["A"]["state"]
    resumed = run(tmp_path / "run")
    a = torch.load(resumed, weights_only=True)["state_dict"]
    b = torch.load(reference, weights_only=True)["state_dict"]
    assert any(k.startswith("code_discriminator.") for k in a)
    assert any(k.startswith("adversary.") for k in a)
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
    header = (tmp_path / "run" / "train_log.csv").read_text().splitlines()[0].split(",")
    assert {"Dz/loss", "Dz/real", "Dz/fake", "E/prior", "A/loss", "A/acc", "E/adversary",
            "E/code_norm", "E/code_norm_heldout"} <= set(header)
    model, _ = load_trained(tmp_path / "run")
    assert model.code_discriminator is not None and model.adversary is not None
    x = torch.rand(2, 3, 16, 16) * 2 - 1
    with torch.no_grad():
        assert model.encode(x).shape == (2, 1024)
    assert np.isfinite(model.heldout_metrics(x, torch.tensor([0, 1]))["E/code_norm_heldout"])
