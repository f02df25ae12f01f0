"""Stages log under their module name, also when run as ``python -m cmal_lcd.stages.<name>``.

dvc.yaml runs every stage with ``python -m``, where a module's ``__name__`` is ``"__main__"``:
``logging.getLogger(__name__)`` would then print ``[__main__]`` instead of the stage. The same
holds for the Hydra app (``python -m cmal_lcd.app``) and ``python -m cmal_lcd.commands``.
"""

from __future__ import annotations

import importlib
import json
import os
import pkgutil
import subprocess
import sys

import numpy as np
from omegaconf import OmegaConf

import cmal_lcd.stages
from cmal_lcd.config import REPO_ROOT, compose

from test_evaluate import SHIFT, write_dataset, write_features

STAGES = sorted(f"cmal_lcd.stages.{m.name}" for m in pkgutil.iter_modules(cmal_lcd.stages.__path__))
MODULES = STAGES + ["cmal_lcd.app", "cmal_lcd.commands"]

#: Runs each module as ``__main__`` (as ``python -m`` does) with ``--help``, then prints the
#: names of every logger created.
SCRIPT = """
import json, logging, runpy, sys, warnings
warnings.simplefilter("ignore", RuntimeWarning)  # runpy: module already imported by its package
for name in sys.argv[1:]:
    sys.argv = [name, "--help"]
    try:
        runpy.run_module(name, run_name="__main__", alter_sys=True)
    except SystemExit:
        pass
print(json.dumps(sorted(logging.Logger.manager.loggerDict)))
"""


def python_env() -> dict:
    """This checkout's ``src`` first on the path (not an installed copy elsewhere)."""
    path = os.pathsep.join(p for p in (str(REPO_ROOT / "src"), os.environ.get("PYTHONPATH"))
                           if p)
    return {**os.environ, "PYTHONPATH": path}


def test_every_stage_module_is_found():
    assert len(STAGES) >= 8 and "cmal_lcd.stages.train" in STAGES


def test_each_module_logger_is_named_after_its_module():
    for name in MODULES:
        module = importlib.import_module(name)
        assert module.logger.name == name, name


def test_run_as_main_no_module_logs_as_dunder_main():
    result = subprocess.run([sys.executable, "-c", SCRIPT, *MODULES], cwd=REPO_ROOT,
                            env=python_env(), capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr[-2000:]
    loggers = json.loads(result.stdout.strip().splitlines()[-1])
    assert "__main__" not in loggers
    assert set(MODULES) <= set(loggers), set(MODULES) - set(loggers)


def test_a_stage_run_with_python_m_logs_under_its_module_name(tmp_path):
    """``python -m cmal_lcd.stages.evaluate`` end to end, as dvc.yaml runs it."""
    params = tmp_path / "params.yaml"
    cfg = compose(["debug=tiny", "matching.ds=5", "matching.r_window=4",
                   f"matching.d_thresh={SHIFT}", "matching.pose_tolerance=1.5"])
    OmegaConf.save(cfg, params)
    protocol = tmp_path / "protocol.json"
    protocol.write_text(json.dumps({"selected": {"centre": "none", "l2": False,
                                                 "enhance": False, "r_window": 4}}))
    out = tmp_path / "evaluation"
    result = subprocess.run(
        [sys.executable, "-m", "cmal_lcd.stages.evaluate", "--params", str(params),
         "--method", "m", "--dataset", str(write_dataset(tmp_path)),
         "--features", str(write_features(tmp_path)), "--protocol", str(protocol),
         "--out", str(out)],
        cwd=tmp_path, env=python_env(), capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr[-2000:]
    assert (out / "metrics.json").is_file()
    lines = [line for line in result.stderr.splitlines() if " INFO " in line]
    assert lines and all(" INFO cmal_lcd.stages.evaluate: " in line for line in lines), lines
    assert "__main__" not in result.stderr
    assert np.isfinite(json.loads((out / "metrics.json").read_text())["r1"]["sunny-foggy"]
                       ["selected"]["recall_at_1"])
