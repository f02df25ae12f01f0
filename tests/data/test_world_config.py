"""The weather world's configuration: composition from conf/, validation with clear messages."""

from __future__ import annotations

import copy

import pytest
from omegaconf import OmegaConf

from cmal_lcd.config import compose
from cmal_lcd.data.world.condition import RANGE_PARAMS, ConditionParams
from cmal_lcd.data.world.config import DataConfig, LoopSpec, novel_fraction
from cmal_lcd.data.world.rng import stream_rng


@pytest.fixture(scope="module")
def data_conf() -> dict:
    return OmegaConf.to_container(compose().data, resolve=True)


def parse(conf: dict) -> DataConfig:
    return DataConfig.from_config(copy.deepcopy(conf))


def test_default_config_has_the_paper_conditions_and_table_ii_pairs(data_conf):
    config = parse(data_conf)
    assert config.condition_names == ["sunny", "foggy", "rainy"]
    assert config.test.pairs == (("foggy", "rainy"), ("foggy", "sunny"), ("rainy", "sunny"))
    assert list(config.test.routes) == ["route1", "route2"]
    assert config.image_size == (64, 64)


def test_every_table_ii_query_has_a_stretch_its_reference_never_visits(data_conf):
    config = parse(data_conf)
    for ref, query in config.test.pairs:
        assert novel_fraction(config.test.windows[ref], config.test.windows[query]) >= 0.15


def test_a_new_condition_is_a_config_file_not_code():
    cfg = compose(["+condition@data.conditions.night=night"])
    config = DataConfig.from_config(cfg.data)
    assert config.condition_names == ["sunny", "foggy", "rainy", "night"]
    assert config.test.windows["night"] == config.test.default_window
    assert config.conditions["night"].ranges["ambient"][1] < 0.1


def test_every_value_comes_from_the_composed_config(data_conf):
    # conf/data/gtav_weather.yaml is the one source: no default in Python overrides or fills in
    config = parse(data_conf)
    for section in ("world", "camera", "train"):
        spec = getattr(config, section)
        for key, value in data_conf[section].items():
            if not isinstance(value, dict):
                expected = tuple(value) if isinstance(value, list) else value
                assert getattr(spec, key) == expected, f"data.{section}.{key}"
    assert config.world.hills_m == data_conf["world"]["hills_m"] == 14.0
    assert config.test.wander.speed == tuple(data_conf["test"]["wander"]["speed"])
    assert config.test.weather_jitter == data_conf["test"]["weather_jitter"]


@pytest.mark.parametrize("section, key", [("world", "hills_m"), ("camera", "pitch_deg"),
                                          ("test", "weather_jitter"), (None, "supersample")])
def test_an_absent_key_is_refused_naming_it_not_defaulted(data_conf, section, key):
    conf = copy.deepcopy(data_conf)
    del (conf[section] if section else conf)[key]
    where = f"data.{section}.{key}" if section else f"data.{key}"
    with pytest.raises(ValueError, match=f"^{where.replace('.', '[.]')}: required"):
        DataConfig.from_config(conf)


def test_unset_condition_keys_take_neutral_defaults():
    condition = ConditionParams.from_config("plain", {})
    assert set(condition.ranges) == set(RANGE_PARAMS)
    assert condition.ranges["rain_density"] == (0.0, 0.0)


@pytest.mark.parametrize("edit, key", [
    (lambda c: c.update(train_per_condition=-5), "data.train_per_condition"),
    (lambda c: c.update(train_per_condition=0), "data.train_per_condition"),
    (lambda c: c["world"].update(size_m=0.0), "data.world.size_m"),
    (lambda c: c["world"].update(cell_m=-0.5), "data.world.cell_m"),
    (lambda c: c["conditions"]["foggy"].update(fog_beta=[-0.01, 0.02]),
     "data.conditions.foggy.fog_beta"),
    (lambda c: c["conditions"]["rainy"].update(wetness=[0.9, 0.1]),
     "data.conditions.rainy.wetness"),
    (lambda c: c["conditions"]["sunny"].update(sun_hue=[0, 1]), "data.conditions.sunny"),
    (lambda c: c["test"].update(pairs=[["foggy", "snowy"]]), "data.test.pairs"),
    (lambda c: c["test"]["windows"].update(snowy=[0.0, 0.5]), "data.test.windows.snowy"),
    (lambda c: c["test"]["windows"].update(rainy=[0.05, 0.75]), "data.test.pairs"),
    (lambda c: c["world"].update(test_region=[0.3, 0.9]), "data.world.train_region/test_region"),
    (lambda c: c["test"]["routes"]["route1"].update(style="desert"),
     "data.test.routes.route1.style"),
    (lambda c: c["test"]["routes"]["route1"].update(length_m=5000.0),
     "data.test.routes.route1.length_m"),
    (lambda c: c.update(image_size=[64]), "data.image_size"),
    (lambda c: c["test"]["wander"].update(speed=[1.2, 0.8]), "data.test.wander.speed"),
    (lambda c: c.update(renderer="raytracer"), "data.renderer"),
    (lambda c: c.update(colour="red"), "data.colour"),
    (lambda c: c["test"].update(weather_jitter=1.5), "data.test.weather_jitter"),
    (lambda c: c["camera"].update(hfov_deg=175.0), "data.camera.hfov_deg"),
    (lambda c: c["world"].update(y_range=[0.9, 0.1]), "data.world.y_range"),
])
def test_bad_values_are_rejected_naming_the_key(data_conf, edit, key):
    conf = copy.deepcopy(data_conf)
    edit(conf)
    with pytest.raises(ValueError, match=key.replace(".", r"\.").replace("/", "/")):
        DataConfig.from_config(conf)


def test_named_streams_are_reproducible_and_independent():
    a = stream_rng(0, "train", "sunny", 3).uniform(size=4)
    assert (a == stream_rng(0, "train", "sunny", 3).uniform(size=4)).all()
    assert not (a == stream_rng(0, "train", "sunny", 4).uniform(size=4)).any()
    assert not (a == stream_rng(1, "train", "sunny", 3).uniform(size=4)).any()
    with pytest.raises(ValueError, match="seed"):
        stream_rng(-1, "train")


def test_loops_are_parsed_and_checked_naming_the_key(data_conf):
    loops = parse(data_conf).test.loops
    assert loops.control == "sunny" and loops.exclude_frames == 50
    assert loops.pairs == (("sunny", "rainy"), ("sunny", "foggy"))
    conf = copy.deepcopy(data_conf)
    del conf["test"]["loops"]
    assert parse(conf).test.loops == LoopSpec()           # absent: no looping route
    for edit, message in [({"control": "snowy"}, "data.test.loops.control: unknown condition"),
                          ({"pairs": [["sunny", "sunny"]]}, "data.test.loops.pairs"),
                          ({"exclude_frames": -1}, "data.test.loops.exclude_frames"),
                          ({"laps": 3}, "data.test.loops.laps: unknown key")]:
        conf = copy.deepcopy(data_conf)
        conf["test"]["loops"].update(edit)
        with pytest.raises(ValueError, match=message):
            parse(conf)
    conf = copy.deepcopy(data_conf)
    conf["test"]["windows"].update(sunny=[0.8, 1.0], foggy=[0.0, 0.5])
    conf["test"]["pairs"] = [["sunny", "foggy"]]
    with pytest.raises(ValueError, match="do not overlap"):
        parse(conf)
