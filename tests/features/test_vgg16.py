"""VGG16 is laid out exactly as torchvision's, so ``vgg16-397923af.pth`` loads without
torchvision."""

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from cmal_lcd.features.vgg16 import VGG16, load_vgg16

# The specification: torchvision's vgg16 state dict, key -> shape (conv layers are
# features.0, 2, 5, 7, 10, 12, 14, 17, 19, 21, 24, 26, 28; linear layers classifier.0, 3, 6).
CONV_LAYERS = {0: (3, 64), 2: (64, 64), 5: (64, 128), 7: (128, 128), 10: (128, 256),
               12: (256, 256), 14: (256, 256), 17: (256, 512), 19: (512, 512), 21: (512, 512),
               24: (512, 512), 26: (512, 512), 28: (512, 512)}
LINEAR_LAYERS = {0: (25088, 4096), 3: (4096, 4096), 6: (4096, 1000)}
TORCHVISION_VGG16_SHAPES = {}
for _i, (_cin, _cout) in CONV_LAYERS.items():
    TORCHVISION_VGG16_SHAPES[f"features.{_i}.weight"] = (_cout, _cin, 3, 3)
    TORCHVISION_VGG16_SHAPES[f"features.{_i}.bias"] = (_cout,)
for _i, (_fin, _fout) in LINEAR_LAYERS.items():
    TORCHVISION_VGG16_SHAPES[f"classifier.{_i}.weight"] = (_fout, _fin)
    TORCHVISION_VGG16_SHAPES[f"classifier.{_i}.bias"] = (_fout,)
POOL_AFTER_CONV = {2, 7, 14, 21, 28}  # max-pool follows these conv layers (its ReLU first)


def meta_vgg16() -> VGG16:
    with torch.device("meta"):
        return VGG16()


def fill_cyclic(net: torch.nn.Module, *, seed: int = 0) -> None:
    """Fill every parameter with a seeded random pool of prime length, repeated (fast)."""
    pool = torch.randn(100_003, generator=torch.Generator().manual_seed(seed)) * 0.02
    with torch.no_grad():
        for p in net.parameters():
            flat = p.view(-1)
            for start in range(0, flat.numel(), pool.numel()):
                n = min(pool.numel(), flat.numel() - start)
                flat[start:start + n] = pool[:n]


def test_state_dict_keys_and_shapes_are_torchvisions():
    got = {k: tuple(v.shape) for k, v in meta_vgg16().state_dict().items()}
    assert got == TORCHVISION_VGG16_SHAPES


def test_torchvision_format_state_dict_round_trips(vgg16_state_file):
    path = vgg16_state_file(value=0.25)
    net = load_vgg16(path)
    state = net.state_dict()
    assert list(state) == list(TORCHVISION_VGG16_SHAPES)
    assert all(torch.all(v == 0.25) for v in state.values())
    assert not net.training


def test_a_state_dict_missing_a_layer_is_rejected_naming_the_parameter(vgg16_state_file):
    path = vgg16_state_file(drop=("classifier.3.weight",))
    with pytest.raises(ValueError, match=r"(?s)vgg16_weights.*classifier\.3\.weight"):
        load_vgg16(path)


def test_a_missing_file_is_rejected(tmp_path):
    with pytest.raises(ValueError, match="vgg16_weights"):
        load_vgg16(tmp_path / "nope.pth")


def reference_forward(state: dict, x: torch.Tensor) -> dict:
    """torchvision's VGG16 written out from the key names alone."""
    for i in sorted(CONV_LAYERS):
        x = F.relu(F.conv2d(x, state[f"features.{i}.weight"], state[f"features.{i}.bias"],
                            padding=1))
        if i in POOL_AFTER_CONV:
            x = F.max_pool2d(x, 2, 2)
    x = torch.flatten(F.adaptive_avg_pool2d(x, (7, 7)), 1)
    fc6 = F.relu(F.linear(x, state["classifier.0.weight"], state["classifier.0.bias"]))
    fc7 = F.relu(F.linear(fc6, state["classifier.3.weight"], state["classifier.3.bias"]))
    logits = F.linear(fc7, state["classifier.6.weight"], state["classifier.6.bias"])
    return {"fc6": fc6, "fc7": fc7, "logits": logits}


def test_fc6_fc7_and_logits_match_torchvisions_layer_order():
    net = meta_vgg16().to_empty(device="cpu").eval()
    fill_cyclic(net)
    x = torch.randn(2, 3, 32, 32, generator=torch.Generator().manual_seed(1))
    with torch.inference_mode():
        expected = reference_forward(net.state_dict(), x)
        got = {"fc6": net.fully_connected_features(x, layer="fc6"),
               "fc7": net.fully_connected_features(x, layer="fc7"), "logits": net(x)}
    for name in expected:
        assert got[name].shape == expected[name].shape
        np.testing.assert_allclose(got[name].numpy(), expected[name].numpy(), rtol=1e-4, atol=1e-6,
                                   err_msg=name)
    assert got["fc6"].shape == (2, 4096) and float(got["fc6"].min()) >= 0.0
    assert float(got["fc6"].max()) > 0.0


def test_unknown_layer_is_rejected():
    with pytest.raises(ValueError, match="layer"):
        meta_vgg16().fully_connected_features(torch.empty(1, 3, 32, 32, device="meta"), layer="fc8")
