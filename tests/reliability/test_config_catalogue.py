"""Catalogue: configuration (docs/reliability.md, "Config").

Unknown keys, wrong types and values out of range are rejected with a message naming the key:
by Hydra for overrides of keys that do not exist, and by the typed schema (cmal_lcd.schema) at
every composition and every params.yaml load: the stages read only checked configs and hold no
parser or list of keys of their own. The libraries that take values from Python check what a
direct call may get wrong (``DataConfig.from_config`` applies the schema to ``data``;
``SeqSLAMParams`` and the extractors check their arguments); :func:`unchecked` composes a
config that never went through the schema. A
stale `params.yaml` is what DVC runs (it is DVC's source of truth and may legitimately hold
overrides such as `debug=tiny`); the CI test `tests/test_config.py` catches a committed stale
one, and `cmal-lcd compose-params` refreshes it.
"""

from __future__ import annotations

import shutil

import pytest
import yaml
from hydra.errors import ConfigCompositionException
from omegaconf import OmegaConf

from cmal_lcd.config import CONF_DIR, compose, compose_params_yaml
from cmal_lcd.schema import SchemaError
from cmal_lcd.data.world.config import DataConfig
from cmal_lcd.features import build_extractor, extractor_conf
from cmal_lcd.matching import SeqSLAMParams

META = {"conditions": ["sunny", "foggy", "rainy"], "image_size": [32, 32]}


def unchecked(overrides: list[str]):
    """Hydra's composition of ``conf/`` without :func:`cmal_lcd.config.check_config`."""
    from hydra import compose as hydra_compose
    from hydra import initialize_config_dir

    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        return hydra_compose(config_name="config", overrides=overrides)


#: Every bad override of this catalogue, and the key its refusal names.
BAD_OVERRIDES = [
    ("+matching.dss=3", r"matching\.dss"), ("+data.worldd=3", r"data\.worldd"),
    ("+features.batchsize=3", r"features\.batchsize"),
    ("+models.cmal.iteration=3", r"models\.cmal\.iteration"),
    ("matching.ds=abc", r"matching\.ds"), ("matching.ds=2.5", r"matching\.ds"),
    ("matching.v_min=fast", r"matching\.v_min"), ("matching.r_window=wide", r"matching\.r_window"),
    ("matching.enhance=maybe", r"matching\.enhance"),
    ("matching.d_thresh=near", r"matching\.d_thresh"),
    ("matching.d_thresh=-1", r"matching\.d_thresh"),
    ("matching.pose_tolerance=far", r"matching\.pose_tolerance"),
    ("matching.pose_tolerance=-2.0", r"matching\.pose_tolerance"),
    ("data.image_size=big", r"data\.image_size"),
    ("data.train_per_condition=many", r"data\.train_per_condition"),
    ("data.train_per_condition=0", r"data\.train_per_condition"),
    ("features.batch_size=abc", r"features\.batch_size"),
    ("features.batch_size=0", r"features\.batch_size"),
    ("matching.sad.width=wide", r"matching\.sad\.width"),
    ("matching.sad.patch=-1", r"matching\.sad\.patch"),
    ("models.cmal.iterations=ten", r"models\.cmal\.iterations"),
    ("models.cmal.iterations=-1", r"models\.cmal\.iterations"),
]


@pytest.mark.parametrize("override, key", BAD_OVERRIDES)
def test_every_bad_override_is_refused_at_composition_naming_the_key(override, key):
    with pytest.raises(SchemaError, match=f"^{key}"):
        compose(["debug=tiny", override])

# ------------------------------------------------------------------------------ unknown keys


def test_overriding_a_key_that_does_not_exist_is_refused_by_hydra_naming_it():
    with pytest.raises(ConfigCompositionException, match=r"matching\.dss"):
        compose(["debug=tiny", "matching.dss=3"])


def test_unknown_data_key_is_refused_naming_it():
    cfg = unchecked(["debug=tiny", "+data.worldd=3"])
    with pytest.raises(ValueError, match=r"^data\.worldd: unknown key"):
        DataConfig.from_config(cfg.data)


def test_unknown_model_key_is_refused_naming_it():
    from cmal_lcd.models import build_model
    from cmal_lcd.models.config import model_config

    node = OmegaConf.to_container(unchecked(["debug=tiny", "+models.cmal.iteration=3"]).models.cmal)
    with pytest.raises(ValueError, match="iteration"):
        model_config("cmal", node)
    with pytest.raises(ValueError, match="iteration"):
        build_model("cmal", node, image_size=32, n_conditions=3)


# -------------------------------------------------------------------------------- wrong types

@pytest.mark.parametrize("override, name", [
    ("matching.ds=abc", "ds"),
    ("matching.ds=2.5", "ds"),
    ("matching.v_min=fast", "v_min"),
    ("matching.r_window=wide", "r_window"),
    ("matching.enhance=maybe", "enhance"),
])
def test_wrong_type_of_a_seqslam_parameter_is_named(override, name):
    cfg = unchecked(["debug=tiny", override])
    with pytest.raises(ValueError, match=name):
        SeqSLAMParams.from_config(cfg.matching)


@pytest.mark.parametrize("override, name", [
    ("data.image_size=big", r"data\.image_size"),
    ("data.train_per_condition=many", r"data\.train_per_condition"),
    ("data.train_per_condition=0", r"data\.train_per_condition"),
])
def test_wrong_type_of_a_data_key_is_named(override, name):
    with pytest.raises(ValueError, match=name):
        DataConfig.from_config(unchecked(["debug=tiny", override]).data)


@pytest.mark.parametrize("override, name", [
    ("features.batch_size=abc", r"features\.batch_size"),
    ("features.batch_size=0", r"features\.batch_size"),
    ("matching.sad.width=wide", r"matching\.sad\.width"),
    ("matching.sad.patch=-1", r"matching\.sad\.patch"),
])
def test_wrong_type_of_a_feature_key_is_named(override, name):
    cfg = unchecked(["debug=tiny", override])
    with pytest.raises(ValueError, match=name):
        build_extractor("sad", conf=extractor_conf(cfg, "sad", dataset_meta=META))


def test_wrong_type_of_a_model_key_is_named():
    from cmal_lcd.models.config import model_config

    cfg = unchecked(["debug=tiny", "models.cmal.iterations=ten"])
    node = OmegaConf.to_container(cfg.models.cmal)
    with pytest.raises(ValueError, match="iterations"):
        model_config("cmal", node)


def test_negative_model_iterations_are_named():
    from cmal_lcd.models.config import model_config

    cfg = unchecked(["debug=tiny", "models.cmal.iterations=-1"])
    node = OmegaConf.to_container(cfg.models.cmal)
    with pytest.raises(ValueError, match="iterations"):
        model_config("cmal", node)


# ---------------------------------------------------------------------- stale params.yaml

def test_editing_conf_makes_params_yaml_stale_until_compose_params(tmp_path):
    conf = tmp_path / "conf"
    shutil.copytree(CONF_DIR, conf)
    params = compose_params_yaml(["debug=tiny"], output=tmp_path / "params.yaml",
                                 config_dir=conf)
    seqslam = conf / "matching" / "seqslam.yaml"
    seqslam.write_text(seqslam.read_text().replace("ds: 10 ", "ds: 8 ", 1))

    fresh = compose_params_yaml(["debug=tiny"], output=tmp_path / "fresh.yaml", config_dir=conf)
    # what DVC would run: the stale value, until params.yaml is composed again
    assert yaml.safe_load(params.read_text())["matching"]["ds"] == 10
    assert yaml.safe_load(fresh.read_text())["matching"]["ds"] == 8
    assert params.read_text() != fresh.read_text()  # the CI staleness test fails like this

    compose_params_yaml(["debug=tiny"], output=params, config_dir=conf)
    assert params.read_text() == fresh.read_text()
