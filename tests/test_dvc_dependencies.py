"""Every DVC stage declares the code it runs: a change to a module that computes a stage's
numbers must re-run that stage.

The stage module named in a stage's ``cmd`` is read (not imported); each ``cmal_lcd`` module it
imports must lie under one of the stage's ``src/`` dependencies. Exempt are the modules that
only read and write the files passed between stages, name checks, logging and the command
line (:data:`PLUMBING`): a change there cannot change a number without failing a stage test.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src"

#: Modules a stage may import without declaring them (file I/O, names, logging, command line;
#: ``schema.py`` types and checks config values, as ``config.py`` does when loading them).
PLUMBING = {
    "src/cmal_lcd/__init__.py", "src/cmal_lcd/config.py", "src/cmal_lcd/errors.py",
    "src/cmal_lcd/schema.py",
    "src/cmal_lcd/io.py", "src/cmal_lcd/names.py", "src/cmal_lcd/progress.py",
    "src/cmal_lcd/stages/__init__.py", "src/cmal_lcd/data/store.py",
    "src/cmal_lcd/data/codes.py", "src/cmal_lcd/paths.py",
}


def module_file(name: str) -> Path | None:
    """``cmal_lcd.a.b`` -> ``src/cmal_lcd/a/b.py`` (or ``.../b/__init__.py``); None if absent."""
    path = SRC / Path(*name.split("."))
    if (path / "__init__.py").is_file():
        return path / "__init__.py"
    return path.with_suffix(".py") if path.with_suffix(".py").is_file() else None


def imported_files(path: Path) -> set[str]:
    """Repository paths of the ``cmal_lcd`` modules ``path`` imports (anywhere in the file)."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("cmal_lcd"):
            submodules = [f"{node.module}.{a.name}" for a in node.names
                          if module_file(f"{node.module}.{a.name}")]
            names.update(submodules or [node.module])
        elif isinstance(node, ast.Import):
            names.update(a.name for a in node.names if a.name.startswith("cmal_lcd"))
    return {str(module_file(n).relative_to(ROOT)) for n in names if module_file(n)}


def stages() -> dict[str, dict]:
    """Stage definitions by name (a ``foreach`` stage: its ``do`` template)."""
    return {name: stage.get("do", stage)
            for name, stage in yaml.safe_load((ROOT / "dvc.yaml").read_text())["stages"].items()}


def covered(path: str, deps: list[str]) -> bool:
    return any(path == d or path.startswith(d.rstrip("/") + "/") for d in deps)


@pytest.mark.parametrize("name", sorted(stages()))
def test_a_stage_declares_every_module_that_computes_its_numbers(name):
    stage = stages()[name]
    module = re.search(r"(cmal_lcd\.stages\.\w+)", stage["cmd"]).group(1)
    deps = [d for d in stage.get("deps", []) if isinstance(d, str)]
    own = str(module_file(module).relative_to(ROOT))
    assert covered(own, deps), f"{name}: its own module {own} is not a dependency"
    missing = sorted(f for f in imported_files(module_file(module)) - PLUMBING
                     if not covered(f, deps))
    assert not missing, f"{name}: imports {missing} but does not depend on them (dvc.yaml)"


def test_removing_a_code_folder_from_a_stage_is_noticed(monkeypatch):
    """The check itself: the evaluate stage without ``src/cmal_lcd/matching`` fails it."""
    stage = stages()["evaluate"]
    deps = [d for d in stage["deps"] if d != "src/cmal_lcd/matching"]
    files = imported_files(module_file("cmal_lcd.stages.evaluate")) - PLUMBING
    assert any(not covered(f, deps) for f in files)


@pytest.mark.parametrize("name", sorted(stages()))
def test_every_stage_depends_on_the_kernel_pin(name):
    """``import cmal_lcd`` pins torch's and NumPy's CPU kernels (``cmal_lcd.kernels``) in every
    stage's process, so a change of the pin can change any stage's numbers."""
    deps = [d for d in stages()[name].get("deps", []) if isinstance(d, str)]
    assert covered("src/cmal_lcd/kernels.py", deps), name
