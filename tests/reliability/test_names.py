"""Hostile names stay out: every name that reaches a path or a command line is checked.

Names (methods, models, routes, conditions, pairs, drives, sweep names) must match a
conservative pattern (``cmal_lcd.names``); each entry point refuses a hostile name with one
line naming the key or file and the value, before anything is written.
"""

from __future__ import annotations

import json
import os

import numpy as np
import pandas as pd
import pytest
from omegaconf import OmegaConf

from cmal_lcd.commands import main
from cmal_lcd.config import compose, compose_params_yaml, load_params
from cmal_lcd.data.folders import build_folder_dataset
from cmal_lcd.data.store import load_dataset, save_dataset
from cmal_lcd.names import (InvalidNameError, OutsideOutputRootError, check_dataset_names,
                            check_drive_name, check_name, output_path)

INJECTION = "sad; echo X; #"
ESCAPE = "../../../x"
HOSTILE = [INJECTION, ESCAPE, "..", ".hidden", "a/b", "", "a" * 65, "x\ny", "$(id)", "-rf",
           "a b", "ok..ko", None, 3]


@pytest.mark.parametrize("name", ["sad", "cmal_untrained", "route1", "foggy-rainy", "v1.2",
                                  "a" * 64])
def test_ordinary_names_are_accepted(name):
    assert check_name(name, key="k") == name


@pytest.mark.parametrize("name", HOSTILE)
def test_hostile_names_are_refused_naming_the_key_and_the_value(name):
    with pytest.raises(InvalidNameError) as err:
        check_name(name, key="methods[1]")
    message = str(err.value)
    assert message.startswith("methods[1]: unsafe name ") and repr(name) in message
    assert "\n" not in message


def test_a_drive_name_is_exactly_one_route_and_one_condition():
    assert check_drive_name("route1/foggy", key="k") == "route1/foggy"
    for bad in ("route1", "a/b/c", "../x", "route1/..", "/abs", ESCAPE):
        with pytest.raises(InvalidNameError, match="unsafe drive name"):
            check_drive_name(bad, key="k")


# ------------------------------------------------------------------------------ output roots


def test_an_output_path_below_its_root_is_returned_unresolved(tmp_path):
    assert output_path(tmp_path / "out", "pr", "route1", "a-b.csv") == \
        tmp_path / "out" / "pr" / "route1" / "a-b.csv"


@pytest.mark.parametrize("parts", [(ESCAPE,), ("pr", "..", "..", "x.csv"), ("/etc/passwd",)])
def test_an_output_path_outside_its_root_is_refused_naming_it(tmp_path, parts):
    with pytest.raises(OutsideOutputRootError, match="outside the output folder"):
        output_path(tmp_path / "out", *parts)


def test_a_symlink_planted_in_the_output_folder_cannot_redirect_a_write(tmp_path):
    (tmp_path / "out").mkdir()
    (tmp_path / "elsewhere").mkdir()
    os.symlink(tmp_path / "elsewhere", tmp_path / "out" / "pr")
    with pytest.raises(OutsideOutputRootError):
        output_path(tmp_path / "out", "pr", "x.csv")


# ------------------------------------------------------------------------------ composition


def test_composing_a_hostile_method_is_refused_naming_the_item():
    with pytest.raises(InvalidNameError, match=r"methods\[1\]: unsafe name 'sad; echo X; #'"):
        compose(["debug=tiny", "methods=[sad,'sad; echo X; #']"])


def test_composing_a_hostile_folder_route_is_refused_naming_the_key():
    with pytest.raises(InvalidNameError,
                       match=r"data\.test\.route: unsafe name '\.\./\.\./\.\./x'"):
        compose(["data=folders", f"data.test.route={ESCAPE}"])


def test_composing_a_hostile_condition_or_pair_is_refused():
    with pytest.raises(InvalidNameError, match=r"data\.test\.pairs\[0\]"):
        compose(["debug=tiny", "data.test.pairs=[[foggy,'a;b']]"])
    with pytest.raises(InvalidNameError, match=r"model_names\[0\]"):
        compose(["debug=tiny", f"model_names=['{ESCAPE}']"])


def test_compose_params_writes_nothing_for_a_hostile_method(tmp_path):
    output = tmp_path / "params.yaml"
    with pytest.raises(InvalidNameError, match="methods"):
        compose_params_yaml(["debug=tiny", "methods=[sad,'sad; echo X; #']"], output=output)
    assert not output.exists()


def test_the_compose_params_command_refuses_a_hostile_method_in_one_line(tmp_path, capsys):
    output = tmp_path / "params.yaml"
    code = main(["compose-params", "debug=tiny", "methods=[sad,'sad; echo X; #']",
                 "--output", str(output)])
    err = capsys.readouterr().err.strip()
    assert code == 2 and not output.exists()
    assert err.splitlines() == [err] and "methods[1]" in err and "Traceback" not in err


def test_a_stage_refuses_a_params_file_holding_a_hostile_name(tmp_path):
    cfg = OmegaConf.to_container(compose(["debug=tiny"]))
    cfg["methods"] = ["sad", INJECTION]
    path = tmp_path / "params.yaml"
    path.write_text(OmegaConf.to_yaml(cfg))
    with pytest.raises(ValueError, match=r"params\.yaml: methods\[1\]: unsafe name"):
        load_params(path)


def test_the_hydra_app_refuses_a_hostile_method_before_running_a_step(tmp_path):
    from cmal_lcd.app import run_chain

    cfg = compose(["debug=tiny", "app.steps=[evaluate]"], config_name="app")
    cfg.methods = ["sad", ESCAPE]
    with pytest.raises(InvalidNameError, match=r"methods\[1\]"):
        run_chain(cfg, tmp_path)
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------------------ dataset.json


def tiny_dataset() -> tuple[np.ndarray, pd.DataFrame, dict]:
    """Two frames per drive of one route, two training frames; safe names."""
    rows = [dict(split="train", route="", drive="", condition=c, x=np.nan, y=np.nan,
                 heading=np.nan, time=np.nan, s=np.nan) for c in ("sunny", "foggy")]
    for drive, condition in (("r/sunny", "sunny"), ("r/foggy", "foggy")):
        rows += [dict(split="test", route="r", drive=drive, condition=condition, x=float(k),
                      y=0.0, heading=0.0, time=float(k), s=float(k)) for k in range(2)]
    frames = pd.DataFrame(rows)
    frames.insert(0, "frame", np.arange(len(frames)))
    meta = {"kind": "test", "image_size": [2, 2], "conditions": ["sunny", "foggy"],
            "routes": ["r"], "drives": [{"name": "r/sunny"}, {"name": "r/foggy"}],
            "pairs": [["r", "r/sunny", "r/foggy", "sunny-foggy"]]}
    return np.zeros((len(frames), 2, 2, 3), np.uint8), frames, meta


@pytest.mark.parametrize("key, index, value", [
    ("pairs", (0, 3), ESCAPE), ("pairs", (0, 0), INJECTION), ("pairs", (0, 2), "r/../../x"),
    ("routes", (0,), ESCAPE), ("conditions", (1,), INJECTION)])
def test_reading_a_dataset_json_with_a_hostile_name_is_refused_naming_file_and_key(
        tmp_path, key, index, value):
    save_dataset(tmp_path / "ds", *tiny_dataset())
    meta_file = tmp_path / "ds" / "dataset.json"
    meta = json.loads(meta_file.read_text())
    node = meta[key]
    for i in index[:-1]:
        node = node[i]
    node[index[-1]] = value
    meta_file.write_text(json.dumps(meta))
    with pytest.raises(InvalidNameError) as err:
        load_dataset(tmp_path / "ds")
    assert str(meta_file) in str(err.value) and f"{key}[" in str(err.value)
    assert repr(value) in str(err.value)


def test_writing_a_dataset_with_a_hostile_pair_name_is_refused(tmp_path):
    images, frames, meta = tiny_dataset()
    meta["pairs"][0][3] = ESCAPE
    with pytest.raises(InvalidNameError, match=r"pairs\[0\]\[3\]"):
        save_dataset(tmp_path / "ds", images, frames, meta)
    assert not (tmp_path / "ds" / "dataset.json").exists()


def test_a_dataset_json_without_drive_list_checks_the_pairs_drives():
    check_dataset_names({"routes": ["r"], "pairs": [["r", "r/a", "r/b", "a-b"]]}, where="f")
    with pytest.raises(InvalidNameError, match=r"f: pairs\[0\]\[1\]: unsafe drive name"):
        check_dataset_names({"pairs": [["r", ESCAPE, "r/b", "a-b"]]}, where="f")


def test_a_dataset_jsons_loops_are_checked_like_its_pairs():
    check_dataset_names({"loops": [["r", "r/a", "r/a_lap2", "a-a"]]}, where="f")
    with pytest.raises(InvalidNameError, match=r"f: loops\[0\]\[3\]"):
        check_dataset_names({"loops": [["r", "r/a", "r/b", ESCAPE]]}, where="f")


def test_a_folder_dataset_with_a_hostile_route_is_refused_naming_the_key(tmp_path):
    cfg = {"kind": "folders", "image_size": [8, 8], "train": {"dir": str(tmp_path)},
           "test": {"dir": str(tmp_path), "route": ESCAPE, "reference": "a", "query": "b"}}
    with pytest.raises(InvalidNameError, match=r"data\.test\.route: unsafe name"):
        build_folder_dataset(cfg, seed=0)


def test_a_folder_dataset_with_a_hostile_condition_folder_is_refused(tmp_path):
    import cv2

    for name in ("summer", "a; b"):
        (tmp_path / name).mkdir()
        for i in range(4):
            cv2.imwrite(str(tmp_path / name / f"f{i}.png"), np.zeros((8, 8, 3), np.uint8))
    cfg = {"kind": "folders", "image_size": [8, 8], "train": {"dir": str(tmp_path)},
           "test": {"dir": str(tmp_path), "route": "r", "reference": "summer",
                    "query": "a; b"}}
    with pytest.raises(InvalidNameError, match=r"data\.(conditions|test\.query)"):
        build_folder_dataset(cfg, seed=0)


# ------------------------------------------------------------------------------ aggregate, match


def finished_sweep(folder):
    """A sweep folder with one finished job (overrides and flat metrics)."""
    job = folder / "0"
    (job / ".hydra").mkdir(parents=True)
    (job / ".hydra" / "overrides.yaml").write_text("- seed=0\n")
    (job / "metrics.json").write_text(json.dumps({"r/a-b/sad/recall_at_100p": 0.5}))
    return folder


@pytest.mark.parametrize("name", [ESCAPE, INJECTION, ".."])
def test_aggregate_refuses_a_hostile_sweep_name_and_writes_nothing(tmp_path, capsys, name):
    sweep = finished_sweep(tmp_path / "sweep")
    out = tmp_path / "reports" / "sweeps"
    code = main(["aggregate", str(sweep), "--name", name, "--out", str(out)])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "--name" in err and repr(name) in err and "Traceback" not in err
    assert not (tmp_path / "reports").exists() and not (tmp_path / "x").exists()


def test_aggregate_with_a_safe_name_writes_under_its_out_folder(tmp_path):
    sweep = finished_sweep(tmp_path / "sweep")
    assert main(["aggregate", str(sweep), "--name", "ds", "--out", str(tmp_path / "o")]) == 0
    assert (tmp_path / "o" / "ds" / "results.csv").is_file()


@pytest.mark.parametrize("name", [INJECTION, ESCAPE])
def test_match_refuses_a_hostile_feature_name_in_one_line(tmp_path, capsys, name):
    code = main(["match", str(tmp_path / "a"), str(tmp_path / "b"), "--features", name,
                 "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and err.splitlines() == [err] and "--features" in err
    assert not (tmp_path / "out").exists()


def test_a_hostile_name_in_params_yaml_runs_no_shell_code(tmp_path):
    """The issue's probe, through real DVC: ``model_names`` and ``methods`` holding
    ``...;touch PWNED;#`` (a hand-edited ``params.yaml`` or ``dvc exp run -S`` skips
    composition), ``dvc repro`` of those stages. No cmd names its item, so the shell never
    sees the name; the stage reads it from ``$DVC_STAGE`` and refuses it in one line."""
    import shutil
    import subprocess
    import sys
    from pathlib import Path

    import yaml

    root = Path(__file__).resolve().parents[2]
    hostile = "bigan;touch PWNED;#"
    params = yaml.safe_load((root / "params.yaml").read_text())
    params["model_names"] = ["cmal", hostile]
    params["models"][hostile] = params["models"]["bigan"]
    params["methods"] = ["sad", "x;touch PWNED2;#"]
    params["feature_inputs"] = {"sad": params["feature_inputs"]["sad"],
                                "x;touch PWNED2;#": params["feature_inputs"]["sad"]}
    shutil.copy(root / "dvc.yaml", tmp_path / "dvc.yaml")
    (tmp_path / "params.yaml").write_text(yaml.safe_dump(params))
    (tmp_path / "src").symlink_to(root / "src")
    (tmp_path / "data" / "dataset").mkdir(parents=True)
    (tmp_path / "data" / "dataset" / "dataset.json").write_text("{}")
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}:{os.environ['PATH']}"}
    dvc = [sys.executable, "-m", "dvc"]
    subprocess.run(dvc + ["init", "--no-scm", "-q"], cwd=tmp_path, check=True, env=env,
                   timeout=120)
    for stage in (f"train@{hostile}", "extract_features@x;touch PWNED2;#"):
        run = subprocess.run(dvc + ["repro", "--single-item", stage], cwd=tmp_path, env=env,
                             capture_output=True, text=True, timeout=300)
        assert run.returncode != 0
        assert "unsafe name" in run.stdout + run.stderr, run.stdout + run.stderr
    assert not (tmp_path / "PWNED").exists() and not (tmp_path / "PWNED2").exists()
    assert not list(tmp_path.glob("PWNED*"))


def test_the_item_of_a_dvc_stage_is_read_from_dvc_and_checked(monkeypatch):
    from cmal_lcd.stages import stage_item

    monkeypatch.setenv("DVC_STAGE", "train@cmal")
    assert stage_item(None, stage="train", option="--model") == "cmal"
    assert stage_item("bigan", stage="train", option="--model") == "bigan"  # given wins
    monkeypatch.setenv("DVC_STAGE", "sub/dvc.yaml:evaluate@sad")
    assert stage_item(None, stage="evaluate", option="--method") == "sad"
    monkeypatch.setenv("DVC_STAGE", f"evaluate@{INJECTION}")
    with pytest.raises(InvalidNameError, match="--method: unsafe name"):
        stage_item(None, stage="evaluate", option="--method")
    monkeypatch.setenv("DVC_STAGE", "report")
    with pytest.raises(ValueError, match="--method: not given, and this command is not run "
                                         "by DVC as a evaluate@<name> stage"):
        stage_item(None, stage="evaluate", option="--method")
    monkeypatch.delenv("DVC_STAGE")
    with pytest.raises(ValueError, match="--model: not given"):
        stage_item(None, stage="train", option="--model")


@pytest.mark.parametrize("override, named", [
    ("methods=[sad,sad]", r"methods\[1\]: 'sad' is listed twice \(methods\[0\]\)"),
    ("methods=[]", "methods: empty"),
])
def test_a_method_list_that_makes_no_table_is_refused(override, named):
    """Issue 38 item 12: ``methods=[sad,sad]`` and ``methods=[]`` were accepted without a
    word (duplicate rows; empty tables)."""
    with pytest.raises(ValueError, match=named):
        compose([override])
