"""The typed configuration (cmal_lcd.schema), as a specification.

Every composition (``compose``, ``cmal-lcd compose-params``, ``cmal-lcd-run``) and every
``params.yaml`` load (each DVC stage, so also a ``dvc exp run -S`` value) is checked against
the schema: an unknown key, a wrong type or a value out of range is refused with one line that
starts with the key. Values stay in ``conf/``; the schema holds only types and ranges.
"""

from __future__ import annotations

import dataclasses
import subprocess
import sys

import pytest
import yaml
from hydra.core.config_store import ConfigStore
from omegaconf import MISSING, OmegaConf

from cmal_lcd import schema
from cmal_lcd.commands import main
from cmal_lcd.config import CONF_DIR, PARAMS_FILE, compose, compose_params_yaml, load_params
from cmal_lcd.schema import SchemaError

#: Shipped compositions: each must pass, and params.yaml must not change because of the schema.
SHIPPED = [[], ["experiment=nordland"], ["experiment=paper"], ["experiment=seeds"],
           ["debug=tiny"], ["data=folders"], ["data=nordland_full"], ["objective=paper"],
           ["objective=prior"], ["objective=adversary"],
           ["+condition@data.conditions.night=night"],
           ["experiment=nordland", "+nordland/direction=winter_to_summer",
            "+nordland/tolerance=pm2"]]

#: Bad values, and the start of the one-line refusal.
BAD = [
    (["matching.ds=abc"], "matching.ds: Value 'abc' of type 'str' could not be converted"),
    (["seed=banana"], "seed: Value 'banana' of type 'str' could not be converted"),
    (["matching.d_thresh=20.7"], "matching.d_thresh: Value '20.7' of type 'float' could not"),
    (["+matching.dss=3"], "matching.dss: unknown key; known: ds, v_min"),
    (["models.cmal.iterations=-5"], "models.cmal.iterations: must be >= 1, got -5"),
    (["matching.v_min=2", "matching.v_max=1"],
     "matching.v_min: must be <= matching.v_max (1.0), got 2.0"),
    (["matching.ds=0"], "matching.ds: must be >= 1, got 0"),
    (["matching.ds='20'"], "matching.ds: expected int, got str '20'"),
    (["matching.enhance=1"], "matching.enhance: expected bool, got int 1"),
    (["matching.score=best"], "matching.score: must be one of ['ratio', 'sum'], got 'best'"),
    (["models.bigan.encoder_norm=layer"], "models.bigan.encoder_norm: must be one of"),
    (["data.image_size=[64,64,3]"], "data.image_size: must have 2 items, got 3"),
    (["data.kind=video"], "data.kind: must be one of ['gtav_weather', 'folders'], got 'video'"),
    (["+data.conditions.sunny.fog=[0,1]"], "data.conditions.sunny.fog: unknown key"),
    (["data=folders", "data.train.range=[0,10]"], "data.train.range[0]: must be >= 1, got 0"),
    (["data=folders", "+data.test.routes=x"], "data.test.routes: unknown key"),
    (["runtime.threads=0"], "runtime.threads: must be >= 1, got 0"),
    (["+foo=1"], "foo: unknown key"),
    # reversed [low, high] ranges (the renderer used to fail later, in numpy's own words)
    (["data.test.wander.period_frames=[200.0,40.0]"],
     "data.test.wander.period_frames: must be [low, high] with low <= high, got [200.0, 40.0]"),
    (["data.test.wander.speed=[1.1,0.8]"], "data.test.wander.speed: must be [low, high]"),
    (["data.conditions.foggy.fog_beta=[0.02,0.01]"],
     "data.conditions.foggy.fog_beta: must be [low, high]"),
    (["data.world.train_region=[0.5,0.1]"], "data.world.train_region: must be [low, high]"),
    (["data.test.default_window=[0.9,0.2]"], "data.test.default_window: must be [low, high]"),
    (["matching.sad.patch=1"], "matching.sad.patch: must be 0 (off) or >= 2, got 1"),
    (["matching.sad.patch=3"], "matching.sad.patch: 3 must divide width 64 and height 32"),
]


def first_line(exc: BaseException) -> str:
    lines = str(exc).splitlines()
    assert len(lines) == 1, str(exc)
    return lines[0]


# ------------------------------------------------------------------------ shipped configs


@pytest.mark.parametrize("overrides", SHIPPED, ids=" ".join)
def test_every_shipped_composition_passes(overrides):
    compose(overrides)


@pytest.mark.parametrize("overrides", SHIPPED, ids=" ".join)
def test_the_written_params_file_is_what_hydra_composed_and_loads_again(overrides, tmp_path):
    """The check never changes a value: params.yaml is the plain composition."""
    path = compose_params_yaml(overrides, output=tmp_path / "params.yaml")
    assert path.read_text() == OmegaConf.to_yaml(compose(overrides))
    load_params(path)


@pytest.mark.parametrize("overrides", SHIPPED, ids=" ".join)
def test_the_written_params_file_is_byte_for_byte_what_dvc_writes(overrides, tmp_path):
    """compose-params composes once and writes the file itself: it must be what ``dvc exp
    run`` writes from the same overrides, else DVC would see changed params."""
    ours = compose_params_yaml(overrides, output=tmp_path / "ours" / "params.yaml")
    (tmp_path / "dvc").mkdir()
    written_by_dvc(overrides, tmp_path / "dvc" / "params.yaml")
    assert ours.read_bytes() == (tmp_path / "dvc" / "params.yaml").read_bytes()


def test_the_committed_params_yaml_passes_and_is_the_default_composition(tmp_path):
    load_params(PARAMS_FILE)
    fresh = compose_params_yaml(output=tmp_path / "params.yaml")
    assert fresh.read_bytes() == PARAMS_FILE.read_bytes()


def test_the_app_config_passes_with_its_app_node():
    cfg = compose(["debug=tiny"], config_name="app")
    assert "app" in cfg


# ----------------------------------------------------------------------- refused at compose


@pytest.mark.parametrize("overrides, message", BAD, ids=lambda v: " ".join(v)
                         if isinstance(v, list) else "")
def test_a_bad_override_is_refused_at_composition_in_one_line_naming_the_key(overrides, message):
    with pytest.raises(SchemaError) as info:
        compose(overrides)
    assert first_line(info.value).startswith(message)


def test_an_override_of_a_key_that_does_not_exist_is_refused_by_hydra_naming_it():
    with pytest.raises(Exception, match=r"matching\.dss"):
        compose(["matching.dss=3"])


def test_compose_params_refuses_in_one_line_and_writes_nothing(tmp_path, capsys):
    output = tmp_path / "params.yaml"
    assert main(["compose-params", "matching.d_thresh=20.7", "--output", str(output)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.splitlines() == [err] and "matching.d_thresh" in err and "Traceback" not in err
    assert not output.exists()


def test_the_hydra_app_refuses_before_running_a_step(tmp_path):
    """``cmal-lcd-run`` composes with Hydra, then run_chain checks before the first step."""
    from cmal_lcd.app import run_chain

    cfg = compose(["debug=tiny", "app.steps=[evaluate]"], config_name="app")
    cfg.matching.ds = 0
    with pytest.raises(SchemaError, match=r"^matching\.ds: must be >= 1, got 0$"):
        run_chain(cfg, tmp_path)
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------- refused when a stage loads params.yaml


def written_by_dvc(overrides: list[str], path) -> None:
    """``params.yaml`` as ``dvc exp run -S`` writes it: DVC's own composition, no check."""
    from dvc.utils.hydra import compose_and_dump

    compose_and_dump(path, str(CONF_DIR), None, "config", str(path.parent), overrides)


@pytest.mark.parametrize("overrides, message", BAD, ids=lambda v: " ".join(v)
                         if isinstance(v, list) else "")
def test_a_bad_value_written_by_dvc_is_refused_by_the_first_stage_that_loads_it(
        overrides, message, tmp_path):
    path = tmp_path / "params.yaml"
    written_by_dvc(overrides, path)
    with pytest.raises(SchemaError) as info:
        load_params(path)
    assert first_line(info.value).startswith(f"{path}: {message}")


def test_a_hand_edited_params_yaml_with_a_quoted_number_is_refused(tmp_path):
    params = yaml.safe_load(PARAMS_FILE.read_text())
    params["matching"]["d_thresh"] = "20"
    path = tmp_path / "params.yaml"
    path.write_text(yaml.safe_dump(params, sort_keys=False))
    with pytest.raises(SchemaError, match=r"params\.yaml: matching\.d_thresh: expected int"):
        load_params(path)


def test_a_loaded_params_yaml_is_typed_by_the_schema_in_its_own_layout(tmp_path):
    """Readers take values as the schema types them, with no cast of their own: an integer
    written for a float field is read as a float; the keys stay the file's, in its order (what
    a stage records of the config is what was written)."""
    params = yaml.safe_load(PARAMS_FILE.read_text())
    params["matching"] = {"pose_tolerance": 5, **params["matching"]}  # first, an int
    path = tmp_path / "params.yaml"
    path.write_text(yaml.safe_dump(params, sort_keys=False))
    cfg = load_params(path)
    assert type(cfg.matching.pose_tolerance) is float and cfg.matching.pose_tolerance == 5.0
    assert type(cfg.matching.d_thresh) is int
    assert list(cfg.matching) == list(params["matching"])
    assert list(cfg) == list(params)
    assert OmegaConf.to_container(cfg)["data"] == params["data"]  # no field the schema adds


def test_dvc_composes_conf_without_our_schemas(tmp_path):
    """No conf/*.yaml names a ConfigStore schema: DVC's process has none registered. (It does
    import the resolver of ``feature_inputs``, through Hydra's plugin scan, and nothing of the
    config or schema modules.)"""
    code = ("import sys; from dvc.utils.hydra import compose_and_dump; "
            f"compose_and_dump({str(tmp_path / 'p.yaml')!r}, {str(CONF_DIR)!r}, None, 'config', "
            f"{str(tmp_path)!r}, ['matching.ds=8']); "
            "assert 'cmal_lcd.features.inputs' in sys.modules; "
            "assert not {'cmal_lcd.schema', 'cmal_lcd.config'} & set(sys.modules)")
    subprocess.run([sys.executable, "-c", code], check=True, timeout=300)
    assert yaml.safe_load((tmp_path / "p.yaml").read_text())["matching"]["ds"] == 8


# ------------------------------------------------------------------------ the schema itself


def all_fields(cls: type):
    """Every field of a schema dataclass and of the schemas nested in it."""
    for f in dataclasses.fields(cls):
        yield cls, f
        nested = f.default_factory() if f.default_factory is not dataclasses.MISSING else None
        if dataclasses.is_dataclass(nested):
            yield from all_fields(type(nested))


ALL_SCHEMAS = [s for options in schema.GROUP_SCHEMAS.values() for s in options.values()]


@pytest.mark.parametrize("cls", [schema.ConfigSchema, *ALL_SCHEMAS], ids=lambda c: c.__name__)
def test_no_value_is_written_in_the_schema(cls):
    """Values live in conf/ only: a field is MISSING, a nested schema, or ``app: None``."""
    for owner, f in all_fields(cls):
        if f.default_factory is not dataclasses.MISSING:
            assert dataclasses.is_dataclass(f.default_factory()), (owner, f.name)
        elif (owner, f.name) != (schema.ConfigSchema, "app"):
            assert f.default == MISSING, (owner.__name__, f.name, f.default)


def test_composing_registers_every_group_schema_in_hydras_config_store():
    compose()  # registration happens here (and in cmal-lcd-run), not when config is imported
    store = ConfigStore.instance()
    assert "schema.yaml" in store.list("")
    for group, options in schema.GROUP_SCHEMAS.items():
        assert sorted(store.list(f"schema/{group}")) == sorted(f"{n}.yaml" for n in options)


def test_every_group_of_conf_has_a_schema():
    groups = {p.name for p in CONF_DIR.iterdir() if p.is_dir()}
    # experiment, debug and nordland are @package _global_ presets of keys typed elsewhere;
    # hydra holds launcher presets, which Hydra itself types; extractors holds method nodes,
    # each checked by the kind its _target_ names (cmal_lcd.features.check_extractors)
    assert groups - {"experiment", "debug", "nordland", "hydra", "extractors"} <= set(
        schema.GROUP_SCHEMAS)


def test_a_range_rule_with_an_unknown_name_is_a_programming_error():
    with pytest.raises(TypeError, match="minimum"):
        schema.value(minimum=1)


def test_every_low_high_range_is_a_pair_and_a_pair_may_be_a_single_value():
    """``ordered`` fields are the [low, high] pairs; [x, x] (a fixed value) is a valid range."""
    ordered = [(cls.__name__, f.name) for cls in vars(schema).values()
               if dataclasses.is_dataclass(cls) for f in dataclasses.fields(cls)
               if f.metadata.get("ordered")]
    assert ("WanderSchema", "period_frames") in ordered and len(ordered) >= 28
    for cls in vars(schema).values():
        if dataclasses.is_dataclass(cls):
            for f in dataclasses.fields(cls):
                if f.metadata.get("ordered"):
                    assert f.metadata.get("length") == 2, (cls.__name__, f.name)
    compose(["data.test.wander.period_frames=[50.0,50.0]"])


def test_the_condition_schema_has_the_renderers_keys_ranges_as_pairs_colours_as_triples():
    from cmal_lcd.data.world.condition import COLOR_PARAMS, RANGE_PARAMS

    lengths = {f.name: f.metadata["length"] for f in dataclasses.fields(schema.ConditionSchema)}
    assert lengths == {**{k: 2 for k in RANGE_PARAMS}, **{k: 3 for k in COLOR_PARAMS}}
