"""Commands work on the checkout they are run in, never on the one the package came from.

Two checkouts (``conf/`` and ``params.yaml`` copied, which is all composing reads and writes):
``a`` plays the checkout the package was installed from, ``b`` a second clone with its own
``conf/`` (``seed: 7``). Composing in ``b`` must read ``b/conf`` and write ``b/params.yaml``,
and leave ``a`` untouched.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

import cmal_lcd.config as config
from cmal_lcd.commands import main
from cmal_lcd.config import CONF_DIR, REPO_ENV


def make_checkout(root: Path, *, seed: int) -> Path:
    """A checkout with the project's ``conf/`` (top-level ``seed`` set) and a ``params.yaml``
    that is not yet a composition (``seed: -1``)."""
    shutil.copytree(CONF_DIR, root / "conf")
    top = root / "conf" / "config.yaml"
    text = top.read_text()
    assert "\nseed: 0\n" in text
    top.write_text(text.replace("\nseed: 0\n", f"\nseed: {seed}\n"))
    (root / "params.yaml").write_text(f"# checkout {root.name}: not composed yet\nseed: -1\n")
    return root


@pytest.fixture
def two_checkouts(tmp_path, monkeypatch):
    """Checkouts ``a`` (the package's, patched into cmal_lcd.config) and ``b``; cwd = ``b``."""
    a = make_checkout(tmp_path / "a", seed=0)
    b = make_checkout(tmp_path / "b", seed=7)
    monkeypatch.setattr(config, "REPO_ROOT", a)
    monkeypatch.setattr(config, "CONF_DIR", a / "conf")
    monkeypatch.setattr(config, "PARAMS_FILE", a / "params.yaml")
    monkeypatch.delenv(REPO_ENV, raising=False)
    monkeypatch.chdir(b)
    return a, b


def seed_of(params: Path) -> int:
    return yaml.safe_load(params.read_text())["seed"]


def test_compose_params_in_a_second_checkout_writes_its_params_and_leaves_the_first(
        two_checkouts):
    a, b = two_checkouts
    before = (a / "params.yaml").read_bytes()
    assert main(["compose-params", "debug=tiny"]) == 0
    assert seed_of(b / "params.yaml") == 7  # composed from b/conf
    assert (a / "params.yaml").read_bytes() == before


def test_compose_params_in_a_subfolder_uses_the_checkout_above(two_checkouts):
    a, b = two_checkouts
    (b / "notebooks").mkdir()
    os.chdir(b / "notebooks")
    assert main(["compose-params", "debug=tiny"]) == 0
    assert seed_of(b / "params.yaml") == 7 and not (b / "notebooks" / "params.yaml").exists()


def test_repo_option_and_environment_variable_choose_the_checkout(two_checkouts, tmp_path,
                                                                   monkeypatch):
    a, b = two_checkouts
    c = make_checkout(tmp_path / "c", seed=11)
    assert main(["compose-params", "--repo", str(c)]) == 0
    assert seed_of(c / "params.yaml") == 11
    d = make_checkout(tmp_path / "d", seed=13)
    monkeypatch.setenv(REPO_ENV, str(d))
    assert main(["compose-params"]) == 0
    assert seed_of(d / "params.yaml") == 13 and seed_of(b / "params.yaml") == -1  # b untouched


def test_compose_params_outside_any_checkout_is_one_line_naming_the_folder(
        two_checkouts, tmp_path, capsys):
    outside = tmp_path / "elsewhere"
    outside.mkdir()
    os.chdir(outside)
    assert main(["compose-params"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.splitlines() == [err] and str(outside) in err and "conf/config.yaml" in err
    assert not (outside / "params.yaml").exists()


def test_a_repo_option_without_conf_is_one_line_naming_it(two_checkouts, tmp_path, capsys):
    assert main(["compose-params", "--repo", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert f"{tmp_path}: no conf/config.yaml" in err and "--repo" in err


# ------------------------------------------------------------------------------ cmal-lcd-run


def run_app(args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k != REPO_ENV}
    return subprocess.run([sys.executable, "-m", "cmal_lcd.app", *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=300)


def test_cmal_lcd_run_composes_the_conf_of_the_checkout_it_runs_in(tmp_path):
    b = make_checkout(tmp_path / "b", seed=7)
    result = run_app(["--cfg", "job", "debug=tiny"], b)
    assert result.returncode == 0, result.stderr
    assert yaml.safe_load(result.stdout)["seed"] == 7


def test_cmal_lcd_run_outside_a_checkout_is_one_line(tmp_path):
    result = run_app(["--cfg", "job"], tmp_path)
    assert result.returncode == 2
    err = result.stderr.strip()
    assert err.splitlines() == [err] and err.startswith("cmal-lcd-run: error: ")
    assert str(tmp_path) in err
