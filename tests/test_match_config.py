"""``--config OVERRIDE`` of ``match`` and ``loops``: conf/ composed with Hydra overrides gives
their defaults (``--help`` shows them) and their extractor's config, as the pipeline's would."""

import json
import re

import pytest

from cmal_lcd.commands import main
from cmal_lcd.config import compose
from cmal_lcd.workflows.loops_folder import loops_folder
from cmal_lcd.matching import matching_defaults
from test_cli import write_route


def option_default(help_text: str, option: str) -> str:
    """The ``(default: X)`` of ``option`` in argparse's help (one option per entry)."""
    entry = re.search(rf"^  {option} [A-Z_]+(.*?)(?=^  -|\Z)", help_text, re.M | re.S)
    return re.search(r"\(default: ([^)]*)\)", " ".join(entry.group(1).split())).group(1)


def test_without_overrides_the_defaults_are_those_of_the_composed_config():
    assert matching_defaults() == dict(compose().matching)


@pytest.mark.parametrize("command", ["match", "loops"])
def test_help_shows_the_defaults_composed_with_the_overrides(command, capsys):
    with pytest.raises(SystemExit):
        main([command, "--help"])
    assert option_default(capsys.readouterr().out, "--ds") == str(matching_defaults()["ds"])
    with pytest.raises(SystemExit):
        main([command, "--config", "matching.ds=5", "--config", "matching.d_thresh=3",
              "--help"])
    shown = capsys.readouterr().out
    assert option_default(shown, "--ds") == "5"
    assert option_default(shown, "--d-thresh") == "3"


def test_match_uses_and_records_the_composed_config(tmp_path):
    reference = write_route(tmp_path / "sunny", brightness=1.0, seed=1)
    query = write_route(tmp_path / "foggy", brightness=0.6, seed=2)
    overrides = ["experiment=nordland", "matching.ds=5", "matching.d_thresh=3",
                 "matching.sad.width=32", "matching.sad.height=16"]
    out = tmp_path / "out"
    assert main(["match", str(reference), str(query), "--no-figures", "--out", str(out),
                 *[arg for o in overrides for arg in ("--config", o)]]) == 0
    params = json.loads((out / "metrics.json").read_text())["params"]
    assert (params["ds"], params["d_thresh"]) == (5, 3)
    assert (params["sad"]["width"], params["sad"]["height"]) == (32, 16)
    assert params["config_overrides"] == overrides


def test_an_explicit_option_beats_the_config(tmp_path):
    reference = write_route(tmp_path / "sunny", brightness=1.0, seed=1)
    query = write_route(tmp_path / "foggy", brightness=0.6, seed=2)
    out = tmp_path / "out"
    assert main(["match", str(reference), str(query), "--no-figures", "--out", str(out),
                 "--config", "matching.ds=5", "--ds", "7"]) == 0
    params = json.loads((out / "metrics.json").read_text())["params"]
    assert params["ds"] == 7 and params["config_overrides"] == ["matching.ds=5"]


@pytest.mark.parametrize("override", ["experiment=no_such_experiment", "matching.ds=0",
                                      "matching.no_such_key=1"])
def test_a_bad_override_is_one_line_naming_config(override, tmp_path, capsys):
    assert main(["match", "a", "b", "--config", override, "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"cmal-lcd: --config {override}: ") and "\n" not in err
    assert not (tmp_path / "o").exists()


def test_loops_takes_its_defaults_from_the_overrides(tmp_path):
    folder = write_route(tmp_path / "route", brightness=1.0, seed=1)
    record = loops_folder(folder, exclude_frames=5, out_dir=tmp_path / "out",
                          config_overrides=["matching.ds=4", "matching.r_window=6"])
    assert (record["params"]["ds"], record["params"]["r_window"]) == (4, 6)
    assert record["params"]["config_overrides"] == ["matching.ds=4", "matching.r_window=6"]
