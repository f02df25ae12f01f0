"""One definition of the chain: ``dvc.yaml`` and the Hydra app cannot drift apart.

``cmal_lcd.app.CHAIN`` (steps, order, matrix, command-line paths, outputs) over
``cmal_lcd.app.ChainPaths`` (the path layout) is the definition; ``dvc.yaml`` cannot import it,
so these tests read ``dvc.yaml`` (``yaml.safe_load``, ``${...}`` resolved for one method or
model) and fail when a stage's order, matrix, module, command-line paths, outputs or data
dependencies differ from it, or when a stage's ``cli`` would hand ``main`` other arguments
than the app does. All of it is cheap: no stage computes anything here.
"""

from __future__ import annotations

import copy
import functools
import importlib
import re
import shlex
from pathlib import Path

import pytest
import yaml

from cmal_lcd.app import (CHAIN, STEPS, ChainPaths, Step, models_to_train,
                          run_chain, world_note)
from cmal_lcd.config import REPO_ROOT, compose

#: The matrix item each stage is resolved for (any entry of ``methods`` / ``model_names``).
ITEM = {"method": "cmal", "model": "bigan", None: None}
#: Flags naming the matrix item rather than a path (never in a dvc.yaml cmd: the stage reads
#: its item from $DVC_STAGE, cmal_lcd.stages.stage_item).
ITEM_FLAGS = {"--method": "method", "--model": "model"}
#: The repository's layout: ChainPaths rooted at "." gives dvc.yaml's relative paths.
REPO = ChainPaths(Path("."))


@functools.cache
def parsed(name: str) -> dict:
    """The checkout's ``name`` (``dvc.yaml``, ``params.yaml``), parsed once per session:
    :func:`resolve` reads both for every path it resolves."""
    return yaml.safe_load((REPO_ROOT / name).read_text())


def dvc_yaml() -> dict:
    """dvc.yaml, each ``foreach`` stage replaced by its ``do`` template (plus ``foreach``)."""
    spec = copy.deepcopy(parsed("dvc.yaml"))
    spec["stages"] = {name: ({**stage["do"], "foreach": stage["foreach"]} if "do" in stage
                             else stage) for name, stage in spec["stages"].items()}
    return spec


def feature_inputs() -> dict:
    """params.yaml's ``feature_inputs``: what ``extract_features`` iterates over."""
    return copy.deepcopy(parsed("params.yaml")["feature_inputs"])


def dvc_vars() -> dict[str, str]:
    """The string ``vars`` of dvc.yaml (``py``); ``params.yaml`` entries are left out."""
    out: dict[str, str] = {}
    for entry in dvc_yaml().get("vars", []):
        if isinstance(entry, dict):
            out.update({k: str(v) for k, v in entry.items()})
    return out


def resolve(text: str, item: str | None) -> str:
    """``${py}``, ``${item.<key>}`` and ``${key}`` substituted (what DVC does for one matrix
    entry, or for the ``feature_inputs`` entry of method ``item``)."""
    for key, value in dvc_vars().items():
        text = text.replace("${%s}" % key, value)
    if item in feature_inputs():
        own = feature_inputs()[item]
        text = text.replace("${item.file}", own["file"])
        text = re.sub(r"\$\{item\.params\.(\d)\}", lambda m: own["params"][int(m[1])], text)
    return re.sub(r"\$\{(item\.\w+|key)\}", str(item), text)


def out_path(entry) -> str:
    """An ``outs``/``metrics`` entry's path (a string, or a one-key dict with its options)."""
    return entry if isinstance(entry, str) else next(iter(entry))


def matrix_key(stage: dict) -> str | None:
    if "foreach" in stage:  # one stage per method, over feature_inputs (derived from methods)
        return "method"
    matrix = stage.get("matrix") or {}
    assert len(matrix) <= 1, matrix
    return next(iter(matrix), None)


def command(stage: dict, item: str | None) -> tuple[str, list[str]]:
    """``(module, argv)`` of a stage's cmd, after ``python -m``."""
    tokens = shlex.split(resolve(stage["cmd"], item))
    at = tokens.index("-m")
    return tokens[at + 1], tokens[at + 2:]


def flag_paths(argv: list[str]) -> dict[str, str]:
    """``--flag value`` pairs of ``argv``, without ``--params`` and the item flags."""
    assert len(argv) % 2 == 0 and all(a.startswith("--") for a in argv[::2]), argv
    pairs = dict(zip(argv[::2], argv[1::2]))
    assert pairs.pop("--params") == "params.yaml"
    for flag in ITEM_FLAGS:
        pairs.pop(flag, None)
    return pairs


def under(path: str, folder: str) -> bool:
    return path == folder or path.startswith(folder.rstrip("/") + "/")


def data_deps(stage: dict, item: str | None) -> set[str]:
    """A stage's dependencies on files of the chain (code under ``src/`` left out)."""
    resolved = {resolve(d, item) for d in stage.get("deps", []) if isinstance(d, str)}
    return {d for d in resolved if not d.startswith("src/")}


def stage_outs(stage: dict, item: str | None) -> set[str]:
    return {resolve(out_path(o), item) for o in stage.get("outs", []) + stage.get("metrics", [])}


def step(name: str) -> Step:
    return next(s for s in CHAIN if s.name == name)


# ------------------------------------------------------------------------------- the order


def test_the_apps_steps_are_dvc_yamls_stages_in_its_order():
    assert list(dvc_yaml()["stages"]) == list(STEPS)


def test_dvc_yamls_order_is_a_topological_order_of_its_deps_and_outs():
    """Each stage depends only on what earlier stages write (so the app may run them in it)."""
    params = parsed("params.yaml")
    every = {"method": params["methods"], "model": params["model_names"], None: [None]}
    written: list[str] = []
    for name, stage in dvc_yaml()["stages"].items():
        items = every[matrix_key(stage)]
        for dep in {d for item in items for d in data_deps(stage, item)}:
            assert any(under(dep, out) or under(out, dep) for out in written), (
                f"{name} depends on {dep}, which no earlier stage writes")
        written += [o for item in items for o in stage_outs(stage, item)]


def test_the_default_app_steps_are_the_whole_chain_in_order():
    assert list(compose([], config_name="app").app.steps) == list(STEPS)


# ------------------------------------------------------------------- one stage at a time


@pytest.mark.parametrize("name", STEPS)
def test_a_stage_runs_the_apps_module_over_the_apps_matrix(name):
    stage, chain_step = dvc_yaml()["stages"][name], step(name)
    assert matrix_key(stage) == chain_step.matrix
    if chain_step.matrix is not None:
        lists = {"method": "${methods}", "model": "${model_names}"}
        if "foreach" in stage:
            params = parsed("params.yaml")
            assert stage["foreach"] == "${feature_inputs}"
            assert list(feature_inputs()) == params["methods"]
        else:
            assert stage["matrix"][chain_step.matrix] == lists[chain_step.matrix]
    module, argv = command(stage, ITEM[chain_step.matrix])
    assert module == f"cmal_lcd.stages.{chain_step.module}"
    # the item reaches the stage through $DVC_STAGE, never through the shell
    assert not {flag for flag in argv[::2] if flag in ITEM_FLAGS}
    assert not re.search(r"\$\{(item|key)", stage["cmd"]), stage["cmd"]


@pytest.mark.parametrize("name", STEPS)
def test_a_stage_command_names_exactly_the_apps_paths(name):
    chain_step = step(name)
    item = ITEM[chain_step.matrix]
    _, argv = command(dvc_yaml()["stages"][name], item)
    expected = {flag: str(path) for flag, path in chain_step.flags(REPO, item).items()
                if flag not in chain_step.item_flags}
    assert flag_paths(argv) == expected


@pytest.mark.parametrize("name", STEPS)
def test_a_stage_writes_exactly_the_apps_outputs(name):
    """Every DVC output lies in one of the step's outputs, and each of those holds one."""
    chain_step = step(name)
    item = ITEM[chain_step.matrix]
    outs = stage_outs(dvc_yaml()["stages"][name], item)
    app_outs = {str(p) for p in chain_step.outs(REPO, item)}
    assert all(any(under(o, a) for a in app_outs) for o in outs), (outs, app_outs)
    assert all(any(under(o, a) for o in outs) for a in app_outs), (outs, app_outs)


@pytest.mark.parametrize("name", STEPS)
def test_a_stage_depends_on_exactly_the_files_the_app_hands_it(name):
    """Each DVC dependency lies in a path the app hands the step, and each of those holds one
    (``extract_features@cmal`` depends on ``models/cmal/model.pt``, inside ``--models``)."""
    chain_step = step(name)
    item = ITEM[chain_step.matrix]
    outs = set(chain_step.outs(REPO, item))
    inputs = {str(p) for p in chain_step.flags(REPO, item).values() if p not in outs}
    inputs |= {str(p) for p in chain_step.after(REPO)}
    deps = data_deps(dvc_yaml()["stages"][name], item)
    assert all(any(under(d, i) for i in inputs) for d in deps), (deps, inputs)
    assert all(any(under(d, i) for d in deps) for i in inputs), (deps, inputs)


@pytest.mark.parametrize("name", STEPS)
def test_a_stage_cli_hands_main_what_the_app_hands_it(name, monkeypatch):
    """The stage's ``cli`` on its dvc.yaml command line, run as DVC runs it (``$DVC_STAGE``
    set to its address), calls ``main`` with the same keyword arguments and the same slice
    of the config as the app's step (``main`` itself replaced by a recorder): the paths it
    derives from the item are the app's."""
    chain_step = step(name)
    item = ITEM[chain_step.matrix]
    module_name, argv = command(dvc_yaml()["stages"][name], item)
    monkeypatch.setenv("DVC_STAGE", name if item is None else f"{name}@{item}")
    module = importlib.import_module(module_name)
    calls, slices = [], []
    monkeypatch.setattr(module, "stage_config",
                        lambda args, stage, item=None: slices.append((stage, item)) or "cfg")
    monkeypatch.setattr(module, "main", lambda cfg, **kwargs: calls.append(kwargs))
    module.cli(argv)
    assert len(calls) == 1
    # the same slice of the config as the app's step (cmal_lcd.stages.stage_keys)
    assert slices == [(module.__name__, item)]
    via_cli = {k: Path(v) if isinstance(v, (str, Path)) and k != chain_step.item_kwarg else v
               for k, v in calls[0].items()}
    assert via_cli == chain_step.main_kwargs(REPO, item)


def test_the_paths_follow_app_reuse(tmp_path):
    paths = ChainPaths(tmp_path / "job", reuse={"models": tmp_path / "old_models"})
    assert paths.model("cmal") == tmp_path / "old_models" / "cmal"
    assert paths.dataset == tmp_path / "job" / "data" / "dataset"
    assert paths.checkpoints("cmal") == tmp_path / "job" / "checkpoints" / "cmal"
    assert paths.world == tmp_path / "job" / "reports" / "world"


# ------------------------------------------------------------------------ which models


@pytest.mark.parametrize("overrides", [[], ["debug=tiny"], ["experiment=seeds"],
                                       ["experiment=paper"], ["experiment=nordland"]])
def test_the_app_trains_what_dvc_trains_for_every_shipped_config(overrides):
    """dvc.yaml's ``train`` matrix is ``model_names``; the app's follows ``methods``: the
    same models for the default config and every shipped experiment."""
    cfg = compose(overrides)
    assert models_to_train(cfg.methods, cfg.model_names) == list(cfg.model_names)


def test_the_untrained_control_needs_the_trained_cmal_classifier():
    """``cmal_untrained`` is encoded under trained CMAL's classifier, so the app trains CMAL
    for it (else its codes would differ from those of dvc repro)."""
    assert models_to_train(["sad", "cmal_untrained"], ["cmal", "bigan"]) == ["cmal"]
    from cmal_lcd.features import method_model, method_names
    from cmal_lcd.models import MODEL_NAMES

    models = {m: method_model(m) for m in method_names() if method_model(m)}
    assert models["cmal_untrained"] == "cmal"
    assert {m: models[m] for m in ("bigan", "cmal", "cmal_place", "place_encoder")} == {
        "bigan": "bigan", "cmal": "cmal", "cmal_place": "cmal_place",
        "place_encoder": "place_encoder"}
    assert set(models.values()) <= set(MODEL_NAMES)


# ------------------------------------------------------------------ run_chain's dispatch


def record_runs(monkeypatch) -> list[tuple[str, str | None]]:
    runs: list[tuple[str, str | None]] = []
    monkeypatch.setattr(Step, "run", lambda self, cfg, paths, item=None:
                        runs.append((self.name, item)))
    return runs


def test_run_chain_runs_every_step_in_the_chains_order(tmp_path, monkeypatch):
    runs = record_runs(monkeypatch)
    cfg = compose(["debug=tiny", "methods=[sad,cmal_untrained]",
                   "app.steps=[report,evaluate,calibrate_world,dataset,train]"],
                  config_name="app")
    assert run_chain(cfg, tmp_path) == {}
    assert runs == [("dataset", None), ("calibrate_world", None), ("train", "cmal"),
                    ("evaluate", "sad"), ("evaluate", "cmal_untrained"), ("report", None)]


def test_run_chain_skips_the_steps_of_reused_folders(tmp_path, monkeypatch):
    runs = record_runs(monkeypatch)
    (tmp_path / "d").mkdir()
    (tmp_path / "m").mkdir()
    cfg = compose(["debug=tiny", "methods=[sad]", f"app.reuse.dataset={tmp_path / 'd'}",
                   f"app.reuse.models={tmp_path / 'm'}"], config_name="app")
    run_chain(cfg, tmp_path / "job")
    assert [name for name, _ in runs] == [s for s in STEPS if s not in ("dataset", "train")]


def test_calibrate_world_says_why_a_folder_dataset_has_no_world():
    assert world_note(compose(["debug=tiny"])) is None
    cfg = compose(["debug=tiny"])
    cfg.data = {"kind": "folders"}
    assert "no world to calibrate" in world_note(cfg)
