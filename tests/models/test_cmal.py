"""CMAL: the four modules, what each step updates, encoding under C(x), Fig. 11's
reconstruction and translation."""

import numpy as np
import pytest
import torch
from model_helpers import tiny_config

from cmal_lcd.models import build_model, preprocess
from cmal_lcd.models.base import TrainingBatch
from cmal_lcd.models.cmal import CMAL, condition_accuracy, reconstruct_and_translate


def make_model(**overrides) -> CMAL:
    return build_model("cmal", tiny_config("cmal", **overrides), image_size=16, n_conditions=3,
                       seed=0)


def make_batch(images, labels, *, seed=0) -> TrainingBatch:
    rng = np.random.default_rng(seed)
    target = (labels + rng.integers(1, 3, len(labels))) % 3
    return TrainingBatch(x=preprocess(images, image_size=16),
                         condition=torch.from_numpy(labels), target=torch.from_numpy(target),
                         noise=torch.randn(len(labels), 1024,
                                           generator=torch.Generator().manual_seed(seed)))


def snapshot(module):
    return [p.detach().clone() for p in module.parameters()]


def changed(module, before) -> bool:
    return any(not torch.equal(p, q) for p, q in zip(module.parameters(), before))


def test_cmal_has_the_four_modules_and_encodes_1024_floats(frames_and_labels):
    images, _ = frames_and_labels
    model = make_model().eval()
    for module in ("classifier", "encoder", "decoder", "discriminator"):
        assert isinstance(getattr(model, module), torch.nn.Module)
    codes = model.encode(preprocess(images[:5], image_size=16))
    assert codes.shape == (5, 1024) and codes.dtype == torch.float32


def test_encode_is_the_encoder_under_the_classifiers_decision(frames_and_labels):
    images, _ = frames_and_labels
    model = make_model().eval()
    x = preprocess(images[:6], image_size=16)
    decision = model.classify(x).argmax(dim=1)
    with torch.no_grad():
        torch.testing.assert_close(model.encode(x), model.encoder(x, model.one_hot(decision)))
        soft = make_model(encode_condition="softmax").eval()
        probs = soft.classify(x).softmax(dim=1)
        torch.testing.assert_close(soft.encode(x), soft.encoder(x, probs))


def test_each_step_updates_only_its_modules(frames_and_labels):
    images, labels = frames_and_labels
    model = make_model()
    opts = model.make_optimizers()
    batch = make_batch(images[:8], labels[:8])
    modules = ("classifier", "encoder", "decoder", "discriminator")

    def run(step, expected):
        before = {m: snapshot(getattr(model, m)) for m in modules}
        step()
        assert {m for m in modules if changed(getattr(model, m), before[m])} == expected

    run(lambda: model.c_step(batch, opts["C"]), {"classifier"})
    _, fakes = model.synthesize(batch)
    run(lambda: model.d_step(batch, fakes, opts["D"]), {"discriminator"})
    run(lambda: model.g_step(batch, fakes, opts["G"]), {"encoder", "decoder"})
    assert all(p.requires_grad for p in model.discriminator.parameters())


def test_synthesize_makes_the_four_batches_of_fig5_under_their_conditions(frames_and_labels):
    images, labels = frames_and_labels
    model = make_model()
    batch = make_batch(images[:6], labels[:6])
    code, fakes = model.synthesize(batch)
    assert code.shape == (6, 1024)
    assert set(fakes) == {"recon", "trans", "gen_a", "gen_b"}
    assert torch.equal(fakes["recon"][1], batch.condition)
    assert torch.equal(fakes["gen_a"][1], batch.condition)
    assert torch.equal(fakes["trans"][1], batch.target)
    assert torch.equal(fakes["gen_b"][1], batch.target)
    assert all(f.shape == batch.x.shape for f, _ in fakes.values())


def test_training_step_logs_every_module_under_its_prefix(frames_and_labels):
    images, labels = frames_and_labels
    model = make_model()
    logs = model.training_step(make_batch(images[:8], labels[:8]), model.make_optimizers())
    for key in ("D/loss", "D/real", "D/fake", "G/adv", "G/loss", "E/recon", "C/loss", "C/acc"):
        assert key in logs and np.isfinite(logs[key])
    assert 0 <= logs["D/real"] <= 1 and 0 <= logs["C/acc"] <= 1
    # the objective: G/loss = adv * G/adv + recon * E/recon with the configured weights
    weights = tiny_config("cmal")["loss_weights"]
    assert logs["G/loss"] == pytest.approx(weights["adv"] * logs["G/adv"]
                                           + weights["recon"] * logs["E/recon"], rel=1e-5)


def test_reconstruction_weight_zero_removes_the_l2_term(frames_and_labels):
    images, labels = frames_and_labels
    model = make_model(loss_weights={"recon": 0.0})
    logs = model.training_step(make_batch(images[:8], labels[:8]), model.make_optimizers())
    assert logs["G/loss"] == pytest.approx(logs["G/adv"], rel=1e-6)


def test_the_latent_term_is_off_by_default_and_pulls_translations_to_the_code(
        frames_and_labels):
    images, labels = frames_and_labels
    batch = make_batch(images[:8], labels[:8])
    paper = make_model()
    assert "E/latent" not in paper.training_step(batch, paper.make_optimizers())
    model = make_model(loss_weights={"latent": 2.0})
    code, fakes = model.synthesize(batch)
    logs = model.g_step(batch, fakes, model.make_optimizers()["G"], code=code)
    recon = tiny_config("cmal")["loss_weights"]["recon"]
    assert logs["G/loss"] == pytest.approx(logs["G/adv"] + recon * logs["E/recon"]
                                           + 2.0 * logs["E/latent"], rel=1e-5)
    with pytest.raises(ValueError, match="code"):
        model.g_step(batch, model.synthesize(batch)[1], model.make_optimizers()["G"])


def test_missing_or_bad_config_keys_are_named():
    cfg = tiny_config("cmal")
    del cfg["classifier_width"]
    with pytest.raises(ValueError, match="classifier_width"):
        build_model("cmal", cfg, image_size=16, n_conditions=3)
    with pytest.raises(ValueError, match="encode_condition"):
        build_model("cmal", tiny_config("cmal", encode_condition="mean"), image_size=16,
                    n_conditions=3)
    with pytest.raises(ValueError, match="name"):
        build_model("vae", tiny_config("cmal"), image_size=16, n_conditions=3)


def test_reconstruct_and_translate_share_one_code(frames_and_labels):
    images, labels = frames_and_labels
    model = make_model()
    out = reconstruct_and_translate(model, images[:4], labels[:4], labels[:4])
    # translating into the frame's own condition is its reconstruction
    np.testing.assert_array_equal(out["translated_b"], out["recon_a"])
    np.testing.assert_array_equal(out["a"], images[:4])
    other = reconstruct_and_translate(model, images[:4], labels[:4], (labels[:4] + 1) % 3)
    assert {k: v.shape for k, v in other.items()} == {k: (4, 16, 16, 3) for k in other}
    assert all(v.dtype == np.uint8 for v in other.values())
    np.testing.assert_array_equal(other["recon_a"], out["recon_a"])
    assert not np.array_equal(other["translated_b"], other["recon_a"])
    assert model.training  # the mode is restored
    with pytest.raises(ValueError, match="cond_b"):
        reconstruct_and_translate(model, images[:2], 0, 3)


class RedClassifier(torch.nn.Module):
    """Predicts condition 0 when the mean red value is high, else 2."""

    def forward(self, x):
        red = x[:, 0].mean(dim=(1, 2))
        return torch.stack([red, torch.zeros_like(red), -red], dim=1)


def test_condition_accuracy_counts_the_classifiers_hits():
    model = make_model()
    model.classifier = RedClassifier()
    images = np.zeros((4, 16, 16, 3), np.uint8)
    images[:2, ..., 0] = 255  # red frames -> predicted 0
    assert condition_accuracy(model, images, np.array([0, 0, 2, 1])) == pytest.approx(0.75)
    with pytest.raises(ValueError, match="labels"):
        condition_accuracy(model, images, np.array([0, 1]))
