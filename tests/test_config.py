"""conf/ is the single source of configuration; params.yaml is its composition."""

from pathlib import Path

import pytest
import yaml

from cmal_lcd.config import CONF_DIR, PARAMS_FILE, compose, compose_params_yaml

EXPERIMENTS = sorted(p.stem for p in (CONF_DIR / "experiment").glob("*.yaml"))
DEBUGS = sorted(p.stem for p in (CONF_DIR / "debug").glob("*.yaml"))


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


def test_an_unknown_key_is_rejected():
    with pytest.raises(Exception, match="no_such_key"):
        compose(["matching.no_such_key=3"])


def test_dvc_yaml_reads_only_keys_that_exist():
    """Every ``params:`` dependency of dvc.yaml names a key of params.yaml."""
    dvc = yaml.safe_load((Path(CONF_DIR).parent / "dvc.yaml").read_text())
    params = yaml.safe_load(PARAMS_FILE.read_text())
    for name, stage in dvc["stages"].items():
        for entry in stage.get("params", []):
            if isinstance(entry, dict):
                continue
            key = entry.replace("${item.model}", params["model_names"][0])
            node = params
            for part in key.split("."):
                assert part in node, f"stage {name}: params key {entry} not in params.yaml"
                node = node[part]
