"""`cmal-lcd --version`, the short `cmal-lcd-run --help`, and the progress lines of `match`."""

import logging
import shutil
import subprocess
import sys

import pytest
from hydra import compose, initialize_config_dir

import cmal_lcd
from cmal_lcd.commands import main
from test_cli import write_route


def test_version_prints_the_package_version(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["--version"])
    assert exit_info.value.code == 0
    assert capsys.readouterr().out.strip() == f"cmal-lcd {cmal_lcd.__version__}"


@pytest.fixture(scope="module")
def run_help(repo_root):
    command = shutil.which("cmal-lcd-run")
    args = [command] if command else [sys.executable, "-m", "cmal_lcd.app"]
    out = subprocess.run([*args, "--help"], capture_output=True, text=True, timeout=120,
                         cwd=repo_root)
    assert out.returncode == 0, out.stderr
    return out.stdout


def test_run_help_is_short_and_lists_the_config_groups(run_help):
    lines = run_help.splitlines()
    assert len(lines) <= 46 and max(map(len, lines)) <= 100  # one screen
    assert "objective: adversary, paper, prior, prior_adversary" in lines
    assert any(line.startswith("experiment: ") and "paper" in line for line in lines)
    assert "hydra/" not in run_help  # Hydra's own groups stay behind --hydra-help
    assert "models:" not in run_help  # not the whole composed config


def test_every_common_override_in_the_help_composes(run_help, repo_root):
    """Each `KEY=VALUE` example of the help is a real key of the app's config."""
    block = run_help.split("Common overrides:")[1].split("Sweep example:")[0]
    overrides = [token.strip("'") for line in block.splitlines()
                 for token in line.split() if "=" in token]
    assert len(overrides) >= 8
    with initialize_config_dir(config_dir=str(repo_root / "conf"), version_base="1.3"):
        for override in overrides:
            compose(config_name="app", overrides=[override])  # raises on an unknown key


def test_match_logs_its_steps_with_verbose(tmp_path, caplog):
    reference = write_route(tmp_path / "sunny", brightness=1.0, seed=1)
    query = write_route(tmp_path / "foggy", brightness=0.6, seed=2)
    with caplog.at_level(logging.INFO, logger="cmal_lcd"):
        assert main(["-v", "match", str(reference), str(query), "--out",
                     str(tmp_path / "out")]) == 0
    messages = [r.getMessage() for r in caplog.records if r.name.startswith("cmal_lcd.")]
    assert any(m.startswith("match: sad features of 40 reference frames") for m in messages)
    assert any(m.startswith("match: 30 of 40 queries scored") for m in messages)
