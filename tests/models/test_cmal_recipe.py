"""The paper-scale recipe's switches of CMAL (issue 36; not the paper): En's own learning rate
``optimizer.lr_en``, the hinge loss, the R1 penalty and the EMA encoder: each is off in
conf/model/cmal.yaml, and a config must say so (no default in the code)."""

import copy

import pytest
import torch
from model_helpers import tiny_config, weather_frames

from cmal_lcd.config import compose
from cmal_lcd.models import build_model, load_trained, preprocess, train_model
from cmal_lcd.models.base import TrainingBatch
from cmal_lcd.models.cmal import CMAL, r1_penalty
from cmal_lcd.models.training import seeded_noise

SWITCHES = ("adversarial_loss", "r1_gamma", "ema_decay", "prior_divergence")


def make_model(optimizer=None, **overrides) -> CMAL:
    cfg = tiny_config("cmal", **overrides)
    if optimizer is not None:
        cfg["optimizer"] = {**cfg["optimizer"], **optimizer}
    return build_model("cmal", cfg, image_size=16, n_conditions=3, seed=0)


def make_batch(model: CMAL, n: int = 8, *, seed: int = 0) -> TrainingBatch:
    images, labels = weather_frames(n, seed=seed)
    return TrainingBatch(x=preprocess(images, image_size=16), condition=torch.from_numpy(labels),
                         target=torch.from_numpy((labels + 1) % 3),
                         noise=seeded_noise(n, model.code_dim, seed=seed, std=model.prior_std))


def train_steps(model: CMAL, steps: int = 2) -> list[dict]:
    """Logs of ``steps`` training steps; the extra code-critic steps draw their prior samples
    from torch's global generator, seeded here as the training loop seeds it."""
    torch.manual_seed(0)
    optimizers = model.make_optimizers()
    return [model.training_step(make_batch(model, seed=k), optimizers) for k in range(steps)]


@pytest.mark.parametrize("key", SWITCHES)
def test_a_config_without_a_switch_is_refused_naming_it(key):
    """No switch has a default in the code (a model.pt written before it existed too): its
    value, off or on, comes from conf/model/cmal.yaml."""
    cfg = tiny_config("cmal")
    del cfg[key]
    with pytest.raises(ValueError, match=rf"^models\.cmal\.{key}: missing from the model"):
        build_model("cmal", cfg, image_size=16, n_conditions=3)


def test_the_shipped_defaults_are_off():
    cmal = compose().models.cmal
    assert (cmal.adversarial_loss, cmal.r1_gamma, cmal.ema_decay) == ("bce", 0.0, 0.0)
    assert cmal.optimizer.lr_en is None


def test_lr_en_gives_the_encoder_its_own_group_and_equal_rates_change_nothing():
    same = make_model(optimizer={"lr_en": tiny_config("cmal")["optimizer"]["lr_g"]})
    groups = same.make_optimizers()["G"].param_groups
    assert [len(g["params"]) for g in groups] == [len(list(same.encoder.parameters())),
                                                  len(list(same.decoder.parameters()))]
    plain = make_model()
    assert train_steps(same) == train_steps(plain)
    for (key, p), q in zip(plain.state_dict().items(), same.state_dict().values()):
        assert torch.equal(p, q), key
    slow = make_model(optimizer={"lr_en": 1e-6})
    assert [g["lr"] for g in slow.make_optimizers()["G"].param_groups] == [
        1e-6, tiny_config("cmal")["optimizer"]["lr_g"]]
    change = {}
    for name, model in (("slow", slow), ("plain", make_model())):
        before = copy.deepcopy(model.state_dict())
        train_steps(model, 1)
        change[name] = {part: max((model.state_dict()[k] - v).abs().max().item()
                                  for k, v in before.items() if k.startswith(part + "."))
                        for part in ("encoder", "decoder")}
    # Adam's first step moves each weight by about its learning rate
    assert change["slow"]["encoder"] < change["plain"]["encoder"] / 20
    assert change["slow"]["decoder"] == change["plain"]["decoder"]


def test_the_hinge_losses_are_the_hinge_formulas():
    model = make_model(adversarial_loss="hinge")
    logits = torch.tensor([-2.0, -0.5, 0.0, 0.5, 2.0])
    assert model.critic_loss(logits, real=True).item() == pytest.approx(
        (3.0 + 1.5 + 1.0 + 0.5 + 0.0) / 5)
    assert model.critic_loss(logits, real=False).item() == pytest.approx(
        (0.0 + 0.5 + 1.0 + 1.5 + 3.0) / 5)
    assert model.fooling_loss(logits).item() == pytest.approx(0.0)
    bce = make_model()
    assert bce.critic_loss(logits, real=True).item() == pytest.approx(
        torch.nn.functional.softplus(-logits).mean().item())
    logs = train_steps(model)
    assert all(torch.isfinite(torch.tensor(v)) for step in logs for v in step.values())
    assert logs != train_steps(bce)


def test_r1_is_the_squared_input_gradient_of_real_logits_and_is_logged():
    x = torch.randn(4, 3, 2, 2, requires_grad=True)
    weight = torch.randn(12)
    logits = (x.flatten(1) * weight).sum(dim=1)  # d logit_i / d x_i = weight
    assert r1_penalty(logits, x).item() == pytest.approx(weight.pow(2).sum().item(), rel=1e-6)
    model = make_model(r1_gamma=10.0)
    logs = train_steps(model)
    assert all(step["D/r1"] > 0 for step in logs)
    assert "D/r1" not in train_steps(make_model())[0]


def test_the_ema_encoder_averages_the_encoders_weights_and_encodes():
    decay = 0.5
    model = make_model(ema_decay=decay)
    assert model.encoder_ema is not None
    optimizers = model.make_optimizers()
    expected = None
    for k in range(3):
        model.training_step(make_batch(model, seed=k), optimizers)
        current = {n: p.detach().clone() for n, p in model.encoder.named_parameters()}
        expected = current if expected is None else {
            n: decay * expected[n] + (1 - decay) * current[n] for n in current}
    for name, param in model.encoder_ema.module.named_parameters():
        torch.testing.assert_close(param, expected[name], rtol=1e-6, atol=1e-7)
    model.eval()
    x = make_batch(model).x
    with torch.no_grad():
        condition = model.encode_condition(x)
        assert torch.equal(model.encode(x), model.encoder_ema.module(x, condition))
        assert not torch.equal(model.encode(x), model.encoder(x, condition))


def test_the_ema_encoder_is_saved_and_loaded_with_the_model(tmp_path):
    images, labels = weather_frames(24)
    cfg = tiny_config("cmal", ema_decay=0.9, validate_every=0, select="last")
    train_model("cmal", cfg, images, labels, conditions=["sunny", "foggy", "rainy"],
                out_dir=tmp_path, seed=0)
    model, _ = load_trained(tmp_path)
    assert model.encoder_ema is not None
    assert any(k.startswith("encoder_ema.") for k in model.state_dict())


@pytest.mark.parametrize("key, value, message", [
    ("adversarial_loss", "wasserstein", r"^models\.cmal\.adversarial_loss: must be one of"),
    ("r1_gamma", -1.0, r"^models\.cmal\.r1_gamma: must be >= 0"),
    ("ema_decay", 1.0, r"^models\.cmal\.ema_decay: must be < 1"),
])
def test_bad_switch_values_are_named(key, value, message):
    with pytest.raises(ValueError, match=message):
        make_model(**{key: value})


def test_a_row_trained_with_a_switch_on_never_says_paper_objective():
    assert make_model(loss_weights={"prior": 0.0, "adversary": 0.0}).label == \
        "CMAL (paper objective, eqs. 9-12)"
    model = make_model(loss_weights={"prior": 0.0, "adversary": 0.0}, adversarial_loss="hinge",
                       ema_decay=0.999)
    assert model.label == "CMAL (eqs. 9-12) + recipe (hinge loss, EMA 0.999)"
    both = make_model(r1_gamma=10.0, optimizer={"lr_en": 5e-5})
    assert both.label.endswith(" + recipe (R1 10, En lr 5e-05)") and "paper" not in both.label


def test_mmd_is_near_zero_for_one_distribution_and_grows_with_the_gap():
    from cmal_lcd.models.cmal import mmd_squared

    g = torch.Generator().manual_seed(0)
    x, y = torch.randn(64, 32, generator=g), torch.randn(64, 32, generator=g)
    scale = 2.0 * 32
    same = float(mmd_squared(x, y, scale=scale))
    shifted = [float(mmd_squared(x + shift, y, scale=scale)) for shift in (0.5, 1.0, 2.0)]
    shrunk = float(mmd_squared(0.3 * x, y, scale=scale))   # codes smaller than the prior
    assert abs(same) < 0.2 * shifted[0]
    assert shifted[0] < shifted[1] < shifted[2] and shrunk > 5 * abs(same)


def test_mmd_prior_builds_no_code_discriminator_and_pulls_each_conditions_codes():
    from cmal_lcd.models.cmal import mmd_to_prior

    cfg = tiny_config("cmal", prior_divergence="mmd")
    cfg["loss_weights"] = {**cfg["loss_weights"], "prior": 1.0}
    model = build_model("cmal", cfg, image_size=16, n_conditions=3, seed=0)
    assert model.code_discriminator is None and "Dz" not in model.make_optimizers()
    assert "MMD prior" in model.label and "paper objective" not in model.label
    logs = train_steps(model)
    assert all("Dz/loss" not in row and "E/prior" in row for row in logs)
    # codes of condition 0 at the prior, of condition 1 far off: the far ones raise the term
    # and get the larger gradient
    g = torch.Generator().manual_seed(1)
    noise = torch.randn(12, 16, generator=g)
    condition = torch.tensor([0] * 6 + [1] * 6)
    code = torch.cat([torch.randn(6, 16, generator=g), 3 + torch.randn(6, 16, generator=g)])
    split = mmd_to_prior(code, noise, condition, prior_std=1.0)
    assert split > mmd_to_prior(code[:6], noise[:6], condition[:6], prior_std=1.0) + 0.1
    code.requires_grad_(True)
    mmd_to_prior(code, noise, condition, prior_std=1.0).backward()
    assert code.grad[6:].abs().sum() > code.grad[:6].abs().sum()


def test_the_adversarial_prior_is_the_default_and_refuses_an_unknown_divergence():
    assert make_model().prior_divergence == "adversarial"
    assert compose().models.cmal.prior_divergence == "adversarial"
    with pytest.raises(ValueError, match="models.cmal.prior_divergence"):
        make_model(prior_divergence="wasserstein")
