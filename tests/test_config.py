"""conf/ is the single source of configuration; params.yaml is its composition."""


import pytest
import yaml

from cmal_lcd.config import CONF_DIR, PARAMS_FILE, check_config, compose, compose_params_yaml

EXPERIMENTS = sorted(p.stem for p in (CONF_DIR / "experiment").glob("*.yaml"))
DEBUGS = sorted(p.stem for p in (CONF_DIR / "debug").glob("*.yaml"))
DATAS = sorted(p.stem for p in (CONF_DIR / "data").glob("*.yaml"))
#: Keys of the rendered world's ``data`` that a folder dataset does not have (the schema
#: refuses them there).
WORLD_ONLY = ("world", "supersample", "train_per_condition", "renderer", "camera")
FOLDERS = ["data.train.dir=/frames", "data.test.dir=/frames", "data.test.reference=day",
           "data.test.query=night"]


def test_params_yaml_is_the_composition_of_conf(tmp_path):
    fresh = compose_params_yaml(output=tmp_path / "params.yaml")
    assert PARAMS_FILE.read_text() == fresh.read_text(), (
        "params.yaml is stale: conf/ changed; run `cmal-lcd compose-params` and commit it")


def test_default_config_has_every_pipeline_section():
    cfg = compose()
    for key in ("seed", "data", "models", "features", "matching", "methods", "model_names",
                "runtime"):
        assert key in cfg, key
    assert set(cfg.model_names) <= set(cfg.models)
    assert cfg.matching.ds == 10 and cfg.matching.v_min == 0.8 and cfg.matching.v_max == 1.1
    assert cfg.matching.v_step == 0.1 and cfg.matching.d_thresh == 20


@pytest.mark.parametrize("name", EXPERIMENTS)
def test_every_experiment_config_composes(name):
    cfg = compose([f"experiment={name}"])
    assert cfg.seed is not None


@pytest.mark.parametrize("name", DEBUGS)
def test_every_debug_config_composes(name):
    cfg = compose([f"debug={name}"])
    assert cfg.seed is not None


@pytest.mark.parametrize("experiment", EXPERIMENTS)
@pytest.mark.parametrize("name", DEBUGS)
def test_every_debug_config_composes_with_every_experiment(name, experiment):
    """A debug preset needs no deletions (``~data.world``...) whatever the dataset."""
    cfg = compose([f"experiment={experiment}", f"debug={name}"])
    assert cfg.seed is not None


def test_every_dataset_specific_debug_file_names_a_debug_preset_and_a_data_choice():
    """conf/debug/data/<debug>_<data>.yaml is optional in the defaults list: a misspelt name
    would be skipped silently."""
    names = {f"{debug}_{data}" for debug in DEBUGS for data in DATAS}
    files = sorted(p.stem for p in (CONF_DIR / "debug" / "data").glob("*.yaml"))
    assert files and set(files) <= names, set(files) - names


def _tiny_models(cfg):
    for name in cfg.model_names:
        model = cfg.models[name]
        assert model.image_size == 32 and model.width == 4 and model.iterations == 4, name
        assert model.batch_size == 8, name
    assert cfg.features.batch_size == 16 and cfg.features.timing.n_frames == 4
    assert (cfg.matching.sad.width, cfg.matching.sad.height, cfg.matching.sad.patch) == (32, 16, 4)


def test_tiny_nordland_composes_without_world_keys_and_with_tiny_models():
    cfg = compose(["experiment=nordland", "debug=tiny"])
    assert cfg.data.kind == "folders"
    for key in WORLD_ONLY:
        assert key not in cfg.data, key
    assert "routes" not in cfg.data.test and "validation_routes" not in cfg.data.test
    assert list(cfg.data.image_size) == [32, 64]  # Nordland's own frames, already tiny
    _tiny_models(cfg)
    # the experiment's data selection is kept
    assert list(cfg.data.conditions) == ["summer", "winter"]
    assert list(cfg.data.train.range) == [1, 1000]


def test_tiny_on_any_folder_dataset_composes_with_small_frames():
    cfg = compose(["data=folders", "debug=tiny", *FOLDERS])
    for key in WORLD_ONLY:
        assert key not in cfg.data, key
    assert list(cfg.data.image_size) == [32, 32]
    _tiny_models(cfg)


def test_tiny_still_shrinks_the_rendered_world():
    cfg = compose(["debug=tiny"])
    assert cfg.data.kind == "gtav_weather"
    assert cfg.data.supersample == 1 and cfg.data.train_per_condition == 24
    assert cfg.data.world.size_m == 512.0
    assert {road.length_m for road in cfg.data.world.train_roads.values()} == {300.0}
    assert {route.length_m for route in cfg.data.test.routes.values()} == {150.0}
    assert {route.length_m for route in cfg.data.test.validation_routes.values()} == {150.0}
    assert list(cfg.data.image_size) == [32, 32]
    _tiny_models(cfg)


def test_without_debug_no_dataset_specific_debug_file_applies():
    assert compose(["experiment=nordland"]).data.image_size[1] == 64
    cfg = compose([])
    assert cfg.data.world.size_m == 1024.0 and cfg.data.train_per_condition == 2500


def test_an_unknown_key_is_rejected():
    with pytest.raises(Exception, match="no_such_key"):
        compose(["matching.no_such_key=3"])


def test_dvc_yaml_reads_only_keys_that_exist(tmp_path):
    """Every ``params:`` dependency of every stage, as DVC resolves ``dvc.yaml`` (``matrix``
    and ``foreach`` expanded), names a key of params.yaml."""
    from dvc_stages import resolved

    params = yaml.safe_load(PARAMS_FILE.read_text())
    pipeline = resolved(tmp_path)
    assert "extract_features@cmal" in pipeline.stages
    for name, stage in pipeline.stages.items():
        for key in stage.params or ():
            node = params
            for part in key.split("."):
                assert part in node, f"stage {name}: params key {key} not in params.yaml"
                node = node[part]


def test_dvc_exp_run_derives_feature_inputs_from_methods(tmp_path):
    """``dvc exp run`` composes params.yaml itself (DVC's compose_and_dump, in its own
    process); the resolver behind ``feature_inputs`` is there through Hydra's plugin scan
    (hydra_plugins.cmal_lcd_resolvers), so the features stages follow ``-S methods=...``."""
    import subprocess
    import sys

    out = tmp_path / "params.yaml"
    code = ("import sys; from dvc.utils.hydra import compose_and_dump; "
            f"compose_and_dump({str(out)!r}, {str(CONF_DIR)!r}, None, 'config', "
            f"{str(tmp_path)!r}, ['methods=[bigan,sad]']); "
            "assert 'cmal_lcd.config' not in sys.modules")
    subprocess.run([sys.executable, "-c", code], check=True, cwd=tmp_path)
    composed = yaml.safe_load(out.read_text())
    assert composed["feature_inputs"] == {
        "bigan": {"file": "models/bigan/model.pt",
                  "params": ["extractors.bigan", "runtime.threads", "runtime.threads"]},
        "sad": {"file": "src/cmal_lcd/features/sad.py",
                "params": ["extractors.sad", "matching.sad", "runtime.threads"]}}


def test_feature_inputs_set_by_hand_are_refused():
    with pytest.raises(ValueError, match="feature_inputs: .*derived"):
        check_config(compose(["methods=[sad]", "feature_inputs={}"]))


def test_an_unknown_method_is_refused_at_composition_naming_methods():
    with pytest.raises(ValueError, match=r"methods\[1\]: unknown feature method 'vlad'"):
        compose(["methods=[sad,vlad]"])

def test_compose_params_warns_before_writing_a_preset_into_the_tracked_params(tmp_path, capsys):
    """The quick try must not silently turn `dvc repro` into a toy run over the committed
    results: writing a preset into the checkout's params.yaml warns in one line; the default
    composition and a preset written elsewhere do not."""
    import shutil

    from cmal_lcd.commands import main

    shutil.copytree(CONF_DIR, tmp_path / "conf")
    assert main(["compose-params", "--repo", str(tmp_path), "debug=tiny"]) == 0
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "params.yaml now holds a debug=tiny config" in err
    assert "cmal-lcd-run debug=tiny" in err
    assert main(["compose-params", "--repo", str(tmp_path)]) == 0
    assert capsys.readouterr().err == ""
    assert main(["compose-params", "--repo", str(tmp_path), "debug=tiny", "--output",
                 str(tmp_path / "elsewhere.yaml")]) == 0
    assert capsys.readouterr().err == ""


def test_a_params_path_that_is_not_a_file_is_refused_in_one_line_without_reading_it(tmp_path):
    import os

    from cmal_lcd.config import load_params
    from cmal_lcd.io import NotRegularFileError

    fifo = tmp_path / "params.yaml"
    os.mkfifo(fifo)  # opening it for reading would block until a writer comes
    with pytest.raises(NotRegularFileError, match=r"params.yaml: not a regular file \(a FIFO\)"):
        load_params(fifo)
    with pytest.raises(NotRegularFileError, match="a folder"):
        load_params(tmp_path)
