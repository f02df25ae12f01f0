"""Shared conv blocks: pyramid sizes, output shapes and ranges, how conditions enter."""

import pytest
import torch

from cmal_lcd.models.networks import (ConditionClassifier, Decoder, Encoder, JointDiscriminator,
                                      ProjectionDiscriminator, broadcast_condition,
                                      pyramid_depth, pyramid_widths)


@pytest.mark.parametrize("size, depth", [(8, 1), (16, 2), (32, 3), (64, 4), (128, 5)])
def test_pyramid_goes_down_to_4x4(size, depth):
    assert pyramid_depth(size) == depth
    assert pyramid_widths(size, 16)[-1] == 16 * 2 ** (depth - 1)


@pytest.mark.parametrize("size", [4, 12, 48, 0, 64.0])
def test_pyramid_rejects_sizes_that_are_not_powers_of_two(size):
    with pytest.raises(ValueError, match="image_size"):
        pyramid_depth(size)


def test_broadcast_condition_appends_constant_maps():
    x = torch.zeros(2, 3, 4, 4)
    c = torch.tensor([[1.0, 0.0], [0.0, 1.0]])
    out = broadcast_condition(x, c)
    assert out.shape == (2, 5, 4, 4)
    assert torch.equal(out[1, 4], torch.ones(4, 4)) and torch.equal(out[1, 3], torch.zeros(4, 4))
    assert broadcast_condition(x, None) is x


@pytest.mark.parametrize("size", [8, 16, 32])
def test_encoder_and_decoder_shapes(size):
    torch.manual_seed(0)
    enc = Encoder(image_size=size, width=4, code_dim=1024, n_conditions=3)
    dec = Decoder(image_size=size, width=4, code_dim=1024, n_conditions=3)
    x = torch.rand(5, 3, size, size) * 2 - 1
    c = torch.eye(3)[[0, 1, 2, 0, 1]]
    z = enc(x, c)
    assert z.shape == (5, 1024) and z.dtype == torch.float32
    y = dec(z, c)
    assert y.shape == (5, 3, size, size)
    assert y.min() >= -1 and y.max() <= 1


def test_conditional_networks_require_their_condition():
    enc = Encoder(image_size=8, width=2, code_dim=8, n_conditions=2)
    with pytest.raises(ValueError, match="condition"):
        enc(torch.zeros(1, 3, 8, 8))
    plain = Encoder(image_size=8, width=2, code_dim=8)
    with pytest.raises(ValueError, match="condition"):
        plain(torch.zeros(1, 3, 8, 8), torch.ones(1, 2))


def test_the_condition_changes_what_the_decoder_draws():
    torch.manual_seed(0)
    dec = Decoder(image_size=16, width=4, code_dim=32, n_conditions=3).eval()
    z = torch.randn(2, 32)
    assert not torch.allclose(dec(z, torch.eye(3)[[0, 0]]), dec(z, torch.eye(3)[[1, 1]]))


def test_instance_norm_encoder_codes_do_not_depend_on_the_batch():
    torch.manual_seed(0)
    enc = Encoder(image_size=16, width=4, code_dim=64, n_conditions=3, norm="instance")
    x = torch.rand(4, 3, 16, 16) * 2 - 1
    c = torch.eye(3)[[0, 1, 2, 0]]
    torch.testing.assert_close(enc(x, c)[:1], enc(x[:1], c[:1]))


def test_discriminators_score_each_frame_and_use_the_condition():
    torch.manual_seed(0)
    d = ProjectionDiscriminator(image_size=16, width=4, n_conditions=3).eval()
    x = torch.rand(2, 3, 16, 16)
    logits_a, logits_b = d(x, torch.eye(3)[[0, 0]]), d(x, torch.eye(3)[[2, 2]])
    assert logits_a.shape == (2,)
    assert not torch.allclose(logits_a, logits_b)
    joint = JointDiscriminator(image_size=16, width=4, code_dim=32, hidden=8)
    assert joint(x, torch.randn(2, 32)).shape == (2,)
    classifier = ConditionClassifier(image_size=16, width=4, n_conditions=3)
    assert classifier(x).shape == (2, 3)


def test_unknown_norm_is_named():
    with pytest.raises(ValueError, match="norm"):
        Encoder(image_size=8, width=2, code_dim=8, norm="layer")
