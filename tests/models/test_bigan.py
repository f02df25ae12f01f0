"""BiGAN: encoder, generator and joint discriminator; what each step updates."""

import numpy as np
import pytest
import torch
from model_helpers import CONDITIONS, tiny_config, weather_frames

from cmal_lcd.models import build_model, preprocess, train_model
from cmal_lcd.models.base import TrainingBatch
from cmal_lcd.models.bigan import BiGAN
from cmal_lcd.models.networks import JointDiscriminator


def make_model() -> BiGAN:
    return build_model("bigan", tiny_config("bigan"), image_size=16, n_conditions=3, seed=0)


def test_bigan_encodes_1024_floats_without_labels(frames_and_labels):
    images, _ = frames_and_labels
    model = make_model().eval()
    codes = model.encode(preprocess(images[:3], image_size=16))
    assert codes.shape == (3, 1024) and codes.dtype == torch.float32
    torch.testing.assert_close(codes, model.encoder(preprocess(images[:3], image_size=16)))


def test_bigan_step_updates_d_then_e_and_g(frames_and_labels):
    images, labels = frames_and_labels
    model = make_model()
    opts = model.make_optimizers()
    assert set(opts) == {"D", "G"}
    x = preprocess(images[:8], image_size=16)
    noise = torch.randn(8, 1024, generator=torch.Generator().manual_seed(0))
    z, g = model.encoder(x), model.generator(noise)
    d_before = [p.detach().clone() for p in model.discriminator.parameters()]
    e_before = [p.detach().clone() for p in model.encoder.parameters()]
    model.d_step(x, z, g, noise, opts["D"])
    assert any(not torch.equal(p, q) for p, q in zip(model.discriminator.parameters(), d_before))
    assert all(torch.equal(p, q) for p, q in zip(model.encoder.parameters(), e_before))
    d_after = [p.detach().clone() for p in model.discriminator.parameters()]
    model.g_step(x, z, g, noise, opts["G"])
    assert all(torch.equal(p, q) for p, q in zip(model.discriminator.parameters(), d_after))
    assert any(not torch.equal(p, q) for p, q in zip(model.encoder.parameters(), e_before))


def test_bigan_training_step_logs(frames_and_labels):
    images, labels = frames_and_labels
    model = make_model()
    batch = TrainingBatch(x=preprocess(images[:8], image_size=16),
                          condition=torch.from_numpy(labels[:8]),
                          target=torch.from_numpy(labels[:8]), noise=torch.randn(8, 1024))
    logs = model.training_step(batch, model.make_optimizers())
    for key in ("D/loss", "D/real", "D/fake", "G/adv", "E/adv"):
        assert np.isfinite(logs[key])
    heldout = model.heldout_metrics(batch.x, batch.condition)
    assert set(heldout) == {"E/recon_heldout", "E/code_norm_heldout"} and model.training


# ---------------------------------------------------------------- stabilisers (bigan.yaml)


def test_discriminator_dropout_is_random_in_training_only_and_keeps_the_weights_layout():
    torch.manual_seed(0)
    plain = JointDiscriminator(image_size=16, width=4, code_dim=32, hidden=8)
    torch.manual_seed(0)
    dropped = JointDiscriminator(image_size=16, width=4, code_dim=32, hidden=8, dropout=0.5)
    assert plain.state_dict().keys() == dropped.state_dict().keys()
    dropped.load_state_dict(plain.state_dict())
    x, z = torch.rand(4, 3, 16, 16), torch.randn(4, 32)
    plain.eval(), dropped.eval()
    torch.testing.assert_close(dropped(x, z), plain(x, z))  # eval: no dropout
    dropped.train()
    torch.manual_seed(1)
    first = dropped(x, z)
    assert not torch.allclose(first, dropped(x, z))  # train: a fresh mask each call
    with pytest.raises(ValueError, match="dropout"):
        JointDiscriminator(image_size=16, width=4, code_dim=32, dropout=1.0)


def test_the_discriminator_reads_codes_in_units_of_the_prior_std():
    torch.manual_seed(0)
    unit = JointDiscriminator(image_size=16, width=4, code_dim=32, hidden=8).eval()
    scaled = JointDiscriminator(image_size=16, width=4, code_dim=32, hidden=8,
                                prior_std=0.25).eval()
    scaled.load_state_dict(unit.state_dict())
    x, z = torch.rand(3, 3, 16, 16), torch.randn(3, 32)
    with torch.no_grad():
        torch.testing.assert_close(scaled(x, 0.25 * z), unit(x, z))


def test_bigan_config_builds_the_stabilised_discriminator_and_names_bad_values():
    model = build_model("bigan", tiny_config("bigan", prior_std=0.5, discriminator_dropout=0.2),
                        image_size=16, n_conditions=3, seed=0)
    assert model.prior_std == 0.5
    assert model.discriminator.dropout == 0.2 and model.discriminator.prior_std == 0.5
    with pytest.raises(ValueError, match=r"^models\.bigan\.discriminator_dropout: must be <"):
        build_model("bigan", tiny_config("bigan", discriminator_dropout=1.5), image_size=16,
                    n_conditions=3)
    with pytest.raises(ValueError, match=r"^models\.bigan\.prior_std: must be >"):
        build_model("bigan", tiny_config("bigan", prior_std=-1), image_size=16, n_conditions=3)


@pytest.mark.parametrize("key", ["prior_std", "discriminator_dropout", "unary_scores"])
def test_a_config_without_an_option_is_refused_naming_it(key):
    """No option has a default in the code (a model.pt written before the key existed too):
    the value comes from conf/model/bigan.yaml."""
    cfg = tiny_config("bigan")
    del cfg[key]
    with pytest.raises(ValueError, match=rf"^models\.bigan\.{key}: missing from the model"):
        build_model("bigan", cfg, image_size=16, n_conditions=3)


def test_a_killed_bigan_run_with_dropout_resumes_to_the_same_weights(tmp_path):
    # dropout draws from the global torch RNG, which the checkpoint saves and restores
    cfg = tiny_config("bigan", iterations=6, prior_std=0.5, discriminator_dropout=0.2)
    images, labels = weather_frames()

    def run(out, callback=None):
        return train_model("bigan", cfg, images, labels, conditions=CONDITIONS, out_dir=out,
                           seed=0, device="cpu", callback=callback)

    reference = run(tmp_path / "ref")

    def die(iteration, logs):
        if iteration == 3:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run(tmp_path / "run", die)
    a = torch.load(run(tmp_path / "run"), weights_only=True)["state_dict"]
    b = torch.load(reference, weights_only=True)["state_dict"]
    assert all(torch.equal(a[k], b[k]) for k in a)


def test_unary_scores_add_a_frame_and_a_code_critic_to_the_joint_one(frames_and_labels):
    torch.manual_seed(0)
    joint = JointDiscriminator(image_size=16, width=4, code_dim=32, hidden=8)
    torch.manual_seed(0)
    unary = JointDiscriminator(image_size=16, width=4, code_dim=32, hidden=8, unary=True).eval()
    x, z = torch.rand(4, 3, 16, 16), torch.randn(4, 32)
    assert joint.scores(x, z).shape == (4, 1) and unary.scores(x, z).shape == (4, 3)
    torch.testing.assert_close(unary(x, z), unary.scores(x, z)[:, 0])
    extra = set(unary.state_dict()) - set(joint.state_dict())
    assert extra and all(k.startswith(("x_score.", "z_score.")) for k in extra)
    with torch.no_grad():  # the code critic reads the code only, the frame critic the frame only
        s, s_other_z = unary.scores(x, z), unary.scores(x, torch.randn(4, 32))
        s_other_x = unary.scores(torch.rand(4, 3, 16, 16), z)
    torch.testing.assert_close(s[:, 1], s_other_z[:, 1])
    torch.testing.assert_close(s[:, 2], s_other_x[:, 2])

    images, labels = frames_and_labels
    model = build_model("bigan", tiny_config("bigan", unary_scores=True), image_size=16,
                        n_conditions=3, seed=0)
    batch = TrainingBatch(x=preprocess(images[:8], image_size=16),
                          condition=torch.from_numpy(labels[:8]),
                          target=torch.from_numpy(labels[:8]), noise=torch.randn(8, 1024))
    logs = model.training_step(batch, model.make_optimizers())
    for key in ("D/x_real", "D/x_fake", "D/z_real", "D/z_fake"):
        assert 0.0 <= logs[key] <= 1.0
    # E and G are scored by the terms that depend on them: joint, plus code (E) / frame (G)
    assert logs["G/loss"] == pytest.approx(logs["E/adv"] + logs["E/adv_z"] + logs["G/adv"]
                                           + logs["G/adv_x"], rel=1e-5)


def test_the_encoder_can_have_its_own_learning_rate():
    cfg = tiny_config("bigan", optimizer={"lr_e": None})
    plain = build_model("bigan", cfg, image_size=16, n_conditions=3).make_optimizers()["G"]
    assert len(plain.param_groups) == 1  # lr_e null: one group, E and G at lr_g
    model = build_model("bigan", tiny_config("bigan", optimizer={"lr_e": 2e-5}), image_size=16,
                        n_conditions=3, seed=0)
    groups = model.make_optimizers()["G"].param_groups
    lr_g = tiny_config("bigan")["optimizer"]["lr_g"]
    by_lr = {g["lr"]: {id(p) for p in g["params"]} for g in groups}
    assert by_lr == {lr_g: {id(p) for p in model.generator.parameters()},
                     2e-5: {id(p) for p in model.encoder.parameters()}}
