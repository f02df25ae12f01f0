"""BiGAN: encoder, generator and joint discriminator; what each step updates."""

import numpy as np
import torch
from model_helpers import tiny_config

from cmal_lcd.models import build_model, preprocess
from cmal_lcd.models.base import TrainingBatch
from cmal_lcd.models.bigan import BiGAN


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
    assert set(heldout) == {"E/recon_heldout"} and model.training
