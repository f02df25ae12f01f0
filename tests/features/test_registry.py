"""``build_extractor`` picks methods by name from the nodes of ``extractors`` (the built-in
ones declared in ``conf/extractors/builtin.yaml`` as a user's are); ``extractor_conf`` gives
each method the config it needs; ``conf/features/default.yaml`` holds every key the builders
read."""

from pathlib import Path

import numpy as np
import pytest
from omegaconf import OmegaConf

import cmal_lcd.features as features
from cmal_lcd.config import CONF_DIR
from cmal_lcd.features import (METHOD_NAMES, METHOD_TARGET, FeatureExtractor, build_extractor,
                               extractor_conf, located, method_entry)

#: Keys ``extractor_conf`` adds to the features node for every method.
ADDED = {"method", "extractor", "trained_model"}


def composed_like_config():
    """The real config files for the keys the features stage reads."""
    conf = Path(CONF_DIR)
    return OmegaConf.create({
        "seed": 7,
        "features": OmegaConf.load(conf / "features" / "default.yaml"),
        "matching": OmegaConf.load(conf / "matching" / "seqslam.yaml"),
        "models": {"cmal": OmegaConf.load(conf / "model" / "cmal.yaml")},
    })


def test_method_names_in_table_order():
    """The paper's rows and the control first, in the tables' order; extensions after."""
    assert METHOD_NAMES[:6] == ("sad", "dnn", "dnn_head", "bigan", "cmal", "cmal_untrained")
    assert METHOD_NAMES[6:] == ("cmal_place", "place_encoder")


def test_unknown_method_is_rejected_by_name():
    with pytest.raises(ValueError, match="'vlad'"):
        build_extractor("vlad", conf={})
    with pytest.raises(ValueError, match="'vlad'"):
        extractor_conf(composed_like_config(), "vlad")


def build_mean_colour(conf, *, model_dir=None, device="cpu"):
    return FeatureExtractor(name="mean_colour", label="Mean colour", metric="sqeuclidean",
                            weights="none", backend="numpy",
                            encode=lambda im: (im.reshape(len(im), -1, 3).mean(1)
                                               .astype(np.float32)))


def test_a_new_method_is_one_builder_and_one_node():
    cfg = OmegaConf.to_container(composed_like_config(), resolve=True)
    cfg["extractors"] = {**features.built_in_nodes(), "mean_colour": {
        "_target_": METHOD_TARGET, "build": build_mean_colour, "own_file": "mean_colour.py"}}
    extractor = build_extractor("mean_colour", conf=extractor_conf(cfg, "mean_colour"))
    assert extractor(np.full((2, 4, 4, 3), 9, np.uint8)).tolist() == [[9, 9, 9], [9, 9, 9]]


def test_sad_gets_the_matching_thumbnail_settings():
    cfg = composed_like_config()
    conf = extractor_conf(cfg, "sad")
    assert conf["sad"] == OmegaConf.to_container(cfg.matching.sad)
    assert conf["batch_size"] == cfg.features.batch_size


def test_untrained_control_gets_model_seed_and_dataset_sizes():
    cfg = composed_like_config()
    meta = {"conditions": ["sunny", "rainy", "foggy"], "image_size": [96, 160]}
    conf = extractor_conf(cfg, "cmal_untrained", dataset_meta=meta)
    assert conf["model"] == OmegaConf.to_container(cfg.models.cmal)
    assert conf["seed"] == 7 and conf["n_conditions"] == 3
    assert conf["image_size"] == cfg.models.cmal.image_size  # the model's input size
    with pytest.raises(ValueError, match="dataset_meta"):
        extractor_conf(cfg, "cmal_untrained")


def test_other_methods_get_the_features_node_unchanged():
    cfg = composed_like_config()
    for name in ("dnn", "dnn_head", "bigan", "cmal"):
        conf = extractor_conf(cfg, name)
        assert {k: v for k, v in conf.items() if k not in ADDED} == OmegaConf.to_container(
            cfg.features)
        assert conf["method"] == name and conf["extractor"] == features.built_in_nodes()[name]
        assert conf.get("trained_model") == method_entry(name).model


def test_default_config_has_every_key_the_stage_reads():
    conf = OmegaConf.to_container(OmegaConf.load(Path(CONF_DIR) / "features" / "default.yaml"))
    assert conf["batch_size"] >= 1
    assert set(conf["timing"]) == {"repeats", "warmup", "n_frames"}
    assert conf["timing"]["repeats"] >= 1 and conf["timing"]["warmup"] >= 0
    assert set(conf["dnn"]) == {"vgg16_weights", "fallback", "image_size", "vgg16_layer",
                                "efficientnet_layer", "batch_size", "grid", "layer_candidates",
                                "image_size_candidates"}
    assert conf["dnn"]["batch_size"] >= 1
    assert conf["dnn"]["fallback"] == "efficientnet_lite0" and conf["dnn"]["image_size"] == 224
    assert conf["dnn"]["vgg16_layer"] == "fc6"  # the paper's layer
    assert conf["dnn"]["efficientnet_layer"] == "block10" and conf["dnn"]["grid"] == [4, 4]


def test_omegaconf_nodes_are_accepted_as_conf(no_vgg16_in_hub):
    cfg = composed_like_config()
    extractor = build_extractor("dnn", conf=cfg.features)
    assert extractor.label == "DNN (EfficientNet-Lite0, block 10, 4x4, 224 px)"


@pytest.mark.parametrize("name, builder", [("dnn", "build_dnn"), ("dnn_head", "build_dnn_head")])
def test_the_dnn_methods_are_registered_with_their_builders(name, builder):
    from cmal_lcd.features import dnn

    assert located(method_entry(name).build) is getattr(dnn, builder)
    assert method_entry(name).extra_conf is None  # the features node is all they need


def test_both_dnn_methods_build_from_the_real_config_with_labels_naming_the_layer(no_vgg16_in_hub):
    cfg = composed_like_config()
    labels = {name: build_extractor(name, conf=extractor_conf(cfg, name)).label
              for name in ("dnn", "dnn_head")}
    assert labels == {"dnn": "DNN (EfficientNet-Lite0, block 10, 4x4, 224 px)",
                      "dnn_head": "DNN (EfficientNet-Lite0, pooled head)"}
