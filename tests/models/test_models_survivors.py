"""Specifications the mutation run over the model losses showed missing (docs/testing.md).

Expected values come from ``torch.nn.functional.binary_cross_entropy_with_logits`` on scores
fixed here, never from the loss code under test.
"""

import pytest
import torch
import torch.nn.functional as F
from test_objective_signs import bigan, fixed_batch

from cmal_lcd.models.bigan import _score_loss


def bce(logits, target: float) -> float:
    return F.binary_cross_entropy_with_logits(logits, torch.full_like(logits, target)).item()


@pytest.mark.parametrize("real", [True, False])
def test_bigans_score_loss_is_the_sum_over_its_columns(real):
    """Joint, frame and code scores each count once (kills a loop that counts column 0
    twice)."""
    scores = torch.tensor([[0.5, -1.0, 2.0], [1.5, 0.25, -0.75]])
    expected = sum(bce(scores[:, k], float(real)) for k in range(3))
    assert _score_loss(scores, real=real).item() == pytest.approx(expected, rel=1e-6)


def test_bigans_generator_unary_term_is_the_frame_score_of_generated_frames():
    """With unary scores, ``G/adv_x`` is the frame-only score (column 1) of the generator's
    pairs and ``E/adv_z`` the code-only score (column 2) of the encoder's pairs: D is stubbed
    with constant columns that still depend on the inputs, so each term is identifiable."""
    model = bigan(unary_scores=True)
    batch = fixed_batch(model)
    columns = {"enc": (0.3, -0.4, 1.1), "gen": (-0.2, 0.9, -1.3)}

    def scores(x, z):
        kind = "gen" if z is batch.noise else "enc"
        tie = 0.0 * (x.mean(dim=(1, 2, 3)) + z.mean(dim=1))  # keeps the graph to E and G
        return torch.stack([tie + v for v in columns[kind]], dim=1)

    model.discriminator.scores = scores
    opt = model.make_optimizers()["G"]
    logs = model.g_step(batch.x, model.encoder(batch.x), model.generator(batch.noise),
                        batch.noise, opt)
    gen, enc = torch.tensor([columns["gen"]] * 2), torch.tensor([columns["enc"]] * 2)
    assert logs["G/adv_x"] == pytest.approx(bce(gen[:, 1], 1.0), rel=1e-6)
    assert logs["E/adv_z"] == pytest.approx(bce(enc[:, 2], 0.0), rel=1e-6)
    assert logs["G/adv"] == pytest.approx(bce(gen[:, 0], 1.0), rel=1e-6)
    assert logs["E/adv"] == pytest.approx(bce(enc[:, 0], 0.0), rel=1e-6)


def test_extra_code_critic_steps_see_fresh_prior_draws_at_the_prior_scale():
    """The first critic update uses the batch's prior draws; each extra one
    (``code_critic_steps > 1``, 5 in the default config) a fresh draw of the same scale, so
    ``D_z`` does not see one noise batch five times (kills ``step == 0`` mutated to always or
    never take the batch's draws)."""
    from test_cmal_code_prior import make_batch, make_model

    model = make_model(code_critic_steps=3, code_critic_hidden=16,
                       loss_weights={"prior": 1.0, "adversary": 1.0})
    batch = make_batch(model, 8)
    seen = []
    dz_step = model.dz_step

    def spy(critic_batch, code, optimizer):
        seen.append(critic_batch.noise.clone())
        return dz_step(critic_batch, code, optimizer)

    model.dz_step = spy
    torch.manual_seed(123)  # the global stream the extra draws come from (not the batch's)
    model.training_step(batch, model.make_optimizers())
    assert len(seen) == 3
    assert torch.equal(seen[0], batch.noise)
    assert not torch.equal(seen[1], batch.noise) and not torch.equal(seen[2], seen[1])
    for noise in seen[1:]:
        assert noise.shape == batch.noise.shape
        assert float(noise.std()) == pytest.approx(model.prior_std, rel=0.1)


# --- the losses re-run (2026-12-01): configuration the constructors must honour ---------------
# The run's survivors that changed the networks built from a config: norms, hidden widths and
# the prior scale of the code critics dropped for the network's own default (the tiny configs
# happened to use the defaults), the optional keys' defaults, and the accepted boundaries.

def norm_layers(module: torch.nn.Module) -> set[str]:
    return {type(m).__name__ for m in module.modules()
            if isinstance(m, (torch.nn.InstanceNorm2d, torch.nn.BatchNorm2d))}


@pytest.mark.parametrize("name", ["cmal", "bigan"])
def test_encoder_and_decoder_use_the_configured_normalisation(name):
    from model_helpers import tiny_config

    from cmal_lcd.models import build_model

    cfg = tiny_config(name, encoder_norm="batch", decoder_norm="instance")
    model = build_model(name, cfg, image_size=16, n_conditions=3, seed=0)
    decoder = model.decoder if name == "cmal" else model.generator
    assert norm_layers(model.encoder) == {"BatchNorm2d"}
    assert norm_layers(decoder) == {"InstanceNorm2d"}
    cfg = tiny_config(name, encoder_norm="none", decoder_norm="none")
    model = build_model(name, cfg, image_size=16, n_conditions=3, seed=0)
    decoder = model.decoder if name == "cmal" else model.generator
    assert norm_layers(model.encoder) == norm_layers(decoder) == set()


def test_bigans_discriminator_has_the_configured_hidden_width():
    model = bigan(discriminator_hidden=12)
    assert model.discriminator.x_head.out_features == 12
    assert model.discriminator.z_head.out_features == 12


@pytest.mark.parametrize("dropout", [1.0, -0.1])
def test_bigan_refuses_a_dropout_outside_0_to_1_naming_the_value(dropout):
    from model_helpers import tiny_config

    from cmal_lcd.models import build_model

    cfg = tiny_config("bigan", discriminator_dropout=dropout)
    with pytest.raises(ValueError, match=rf"discriminator_dropout.*got {dropout}"):
        build_model("bigan", cfg, image_size=16, n_conditions=3, seed=0)


def cmal_with_critics(**overrides):
    from test_cmal_code_prior import make_model

    return make_model(loss_weights={"prior": 1.0, "adversary": 1.0}, **overrides)


def test_code_critics_have_the_configured_width_and_read_codes_at_the_prior_scale():
    """``D_z(z|c) = w . phi(z/s) + <E c, phi(z/s)>`` and ``A(z) = MLP(z/s)``, ``s = prior_std``
    (networks.py), written out here from the modules' own layers."""
    model = cmal_with_critics(code_critic_hidden=12, prior_std=0.5).eval()
    dz, adversary = model.code_discriminator, model.adversary
    assert dz.linear.in_features == 12 and adversary.body[0].out_features == 12
    z = torch.randn(5, model.code_dim, generator=torch.Generator().manual_seed(0))
    c = F.one_hot(torch.tensor([0, 1, 2, 0, 1]), 3).float()
    with torch.no_grad():
        phi = dz.phi(z / 0.5)
        expected = dz.linear(phi).squeeze(1) + (dz.embed(c) * phi).sum(dim=1)
        assert torch.allclose(dz(z, c), expected)
        assert torch.allclose(adversary(z), adversary.body(z / 0.5))


@pytest.mark.parametrize("key", ["code_critic_hidden", "code_critic_steps"])
def test_a_config_without_a_critic_key_is_refused_naming_it(key):
    """The critics' width and steps come from conf/model/cmal.yaml only (no default in the
    code, for a model.pt written before the keys existed too)."""
    from model_helpers import tiny_config

    from cmal_lcd.models import build_model

    cfg = tiny_config("cmal", loss_weights={"prior": 1.0, "adversary": 1.0})
    del cfg[key]
    with pytest.raises(ValueError, match=rf"^models\.cmal\.{key}: missing from the model"):
        build_model("cmal", cfg, image_size=16, n_conditions=3, seed=0)


def test_one_code_critic_step_and_one_condition_are_accepted():
    assert cmal_with_critics(code_critic_steps=1).code_critic_steps == 1
    from model_helpers import tiny_config

    from cmal_lcd.models import build_model

    model = build_model("cmal", tiny_config("cmal"), image_size=16, n_conditions=1, seed=0)
    assert model.n_conditions == 1


# --- the losses re-run: the logged training numbers --------------------------------------------

def sigmoid_mean(values) -> float:
    return torch.sigmoid(torch.tensor(values)).mean().item()


def test_bigans_d_step_logs_each_columns_mean_score_under_its_name():
    """``D/x_*`` is the frame-only score (column 1), ``D/z_*`` the code-only one (column 2);
    D is stubbed with fixed columns, so every logged value is known beforehand."""
    model = bigan(unary_scores=True)
    batch = fixed_batch(model)
    real_cols, fake_cols = (0.3, -0.4, 1.1), (-0.2, 0.9, -1.3)
    weight = next(model.discriminator.parameters())

    def scores(x, z):
        cols = fake_cols if z is batch.noise else real_cols
        tie = 0.0 * weight.sum()  # a graph to D for the backward pass
        return torch.stack([tie + torch.full((len(x),), v) for v in cols], dim=1)

    model.discriminator.scores = scores
    logs = model.d_step(batch.x, model.encoder(batch.x), model.generator(batch.noise),
                        batch.noise, model.make_optimizers()["D"])
    real_col, fake_col = torch.tensor(real_cols), torch.tensor(fake_cols)
    loss_real = sum(bce(real_col[k:k + 1], 1.0) for k in range(3))
    loss_fake = sum(bce(fake_col[k:k + 1], 0.0) for k in range(3))
    expected = {"D/loss": loss_real + loss_fake, "D/loss_real": loss_real,
                "D/loss_fake": loss_fake,
                "D/real": sigmoid_mean([real_cols[0]]), "D/fake": sigmoid_mean([fake_cols[0]]),
                "D/x_real": sigmoid_mean([real_cols[1]]), "D/x_fake": sigmoid_mean([fake_cols[1]]),
                "D/z_real": sigmoid_mean([real_cols[2]]), "D/z_fake": sigmoid_mean([fake_cols[2]])}
    assert logs.keys() == expected.keys()
    for key, value in expected.items():
        assert logs[key] == pytest.approx(value, rel=1e-6), key


def test_the_logged_code_norm_is_the_mean_euclidean_norm_of_the_codes():
    """``E/code_norm`` (BiGAN and CMAL) is the mean over frames of ``||z||``, not the norm of
    the whole batch."""
    import numpy as np

    model = bigan()
    batch = fixed_batch(model)
    z = model.encoder(batch.x)
    expected = float(np.linalg.norm(z.detach().numpy(), axis=1).mean())
    logs = model.g_step(batch.x, z, model.generator(batch.noise), batch.noise,
                        model.make_optimizers()["G"])
    assert {"G/adv", "E/adv", "G/loss", "E/code_norm"} <= logs.keys()
    assert logs["E/code_norm"] == pytest.approx(expected, rel=1e-5)

    model = cmal_with_critics()
    batch = fixed_batch(model)
    code, fakes = model.synthesize(batch)
    expected = float(np.linalg.norm(code.detach().numpy(), axis=1).mean())
    logs = model.g_step(batch, fakes, model.make_optimizers()["G"], code=code)
    assert logs["E/code_norm"] == pytest.approx(expected, rel=1e-5)


def test_cmals_classifier_step_logs_the_accuracy_of_the_logits_it_was_trained_on():
    import numpy as np

    from test_objective_signs import cmal

    model = cmal()
    batch = fixed_batch(model)
    with torch.no_grad():  # train mode: the same batch statistics as in the step
        predicted = model.classifier(batch.x).argmax(dim=1).numpy()
    expected = float(np.mean(predicted == batch.condition.numpy()))
    logs = model.c_step(batch, model.make_optimizers()["C"])
    assert logs["C/acc"] == pytest.approx(expected)


def test_cmals_d_step_logs_its_loss_as_the_sum_of_its_real_and_fake_parts():
    from test_objective_signs import cmal

    model = cmal()
    batch = fixed_batch(model)
    with torch.no_grad():
        _, fakes = model.synthesize(batch)
    logs = model.d_step(batch, fakes, model.make_optimizers()["D"])
    assert {"D/loss", "D/loss_real", "D/loss_fake", "D/real", "D/fake"} <= logs.keys()
    assert logs["D/loss"] == pytest.approx(logs["D/loss_real"] + logs["D/loss_fake"], rel=1e-6)


def test_condition_accuracy_of_a_single_frame_is_0_or_1():
    from model_helpers import weather_frames
    from test_objective_signs import cmal

    from cmal_lcd.models.cmal import condition_accuracy, predict_conditions

    model = cmal().eval()
    images, labels = weather_frames(1)
    predicted = int(predict_conditions(model, images)[0])
    assert condition_accuracy(model, images, labels) == float(predicted == labels[0])
