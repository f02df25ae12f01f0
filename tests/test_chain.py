"""One definition of the chain: ``dvc.yaml``, which the Hydra app reads (``cmal_lcd.chain``).

These tests check what makes running a stage's ``cmd`` in the app the same as ``dvc repro``
running it: its order is a topological order of its deps and outs, the item reaches the stage
by ``--<key>`` in the app and by ``$DVC_STAGE`` under DVC with the same effect, the paths
``main`` gets are the stage's deps and outs, and the stage defaults are ``dvc.yaml``'s paths.
All of it is cheap: no stage computes anything here (``main`` is replaced by a recorder).
"""

from __future__ import annotations

import importlib
import re
from pathlib import Path

import pytest
from omegaconf import OmegaConf

from cmal_lcd import app
from cmal_lcd.app import models_to_train, run_chain, world_note
from cmal_lcd.chain import matrix_key, read_stages, stage_names, stage_runs, under
from cmal_lcd.config import REPO_ROOT, compose

DVC_YAML = REPO_ROOT / "dvc.yaml"
STAGES = stage_names(DVC_YAML)
#: The matrix item each stage is resolved for (any entry of ``methods`` / ``model_names``).
ITEM = {"method": "cmal", "model": "bigan"}


def default_runs(**kwargs):
    cfg = compose([])
    return stage_runs(DVC_YAML, {"method": list(cfg.methods), "model": list(cfg.model_names)},
                      feature_inputs=OmegaConf.to_container(cfg.feature_inputs), **kwargs)


def one_run(name: str):
    """The run of stage ``name`` for :data:`ITEM` (or its only run)."""
    return next(r for r in default_runs(names=[name]) if r.item in (None, *ITEM.values()))


def main_kwargs(run, monkeypatch, argv=None, *, dvc_stage: bool = False) -> dict:
    """What the stage's ``cli`` hands ``main`` on ``argv`` (default the run's own), recorded;
    with ``dvc_stage`` the item comes from ``$DVC_STAGE``, as under ``dvc repro``."""
    module = importlib.import_module(run.module)
    calls: list[dict] = []
    monkeypatch.setattr(module, "stage_config", lambda args, stage, item=None: (stage, item))
    monkeypatch.setattr(module, "main", lambda cfg, **kw: calls.append({"cfg": cfg, **kw}))
    if dvc_stage:
        monkeypatch.setenv("DVC_STAGE", run.address)
    else:
        monkeypatch.delenv("DVC_STAGE", raising=False)
    module.cli(list(run.argv if argv is None else argv))
    assert len(calls) == 1
    return calls[0]


def paths_of(kwargs: dict) -> set[str]:
    return {str(v) for k, v in kwargs.items() if isinstance(v, Path)}


# ------------------------------------------------------------------------------- the order


def test_dvc_yamls_order_is_a_topological_order_of_its_deps_and_outs():
    """Each stage depends only on what earlier stages write (so the app may run them in it)."""
    written: list[str] = []
    for name in STAGES:
        runs = default_runs(names=[name])
        for dep in {d for r in runs for d in r.deps if not d.startswith("src/")}:
            assert any(under(dep, out) or under(out, dep) for out in written), (
                f"{name} depends on {dep}, which no earlier stage writes")
        written += [o for r in runs for o in r.outs]


def test_the_default_app_runs_every_stage():
    assert compose([], config_name="app").app.steps is None


def test_every_stage_runs_a_stage_module_and_no_item_reaches_a_shell():
    stages, _ = read_stages(DVC_YAML)
    for name, stage in stages.items():
        assert re.match(r"\$\{py\} cmal_lcd\.stages\.\w+ --params params\.yaml", stage["cmd"])
        assert not re.search(r"\$\{(item|key)", stage["cmd"]), stage["cmd"]
        key = matrix_key(stage)
        if "foreach" in stage:
            assert stage["foreach"] == "${feature_inputs}"
        elif key is not None:
            assert stage["matrix"][key] == {"method": "${methods}", "model": "${model_names}"}[key]


# ------------------------------------------------------------------- one stage at a time


@pytest.mark.parametrize("name", STAGES)
def test_the_apps_item_option_and_dvcs_stage_address_give_main_the_same_call(name, monkeypatch):
    """The app passes the item as ``--method cmal``; DVC sets ``$DVC_STAGE=evaluate@cmal``."""
    run = one_run(name)
    via_app = main_kwargs(run, monkeypatch)
    if run.item is not None:
        dvc_argv = list(run.argv[:-2])  # without --<key> <item>
        assert main_kwargs(run, monkeypatch, dvc_argv, dvc_stage=True) == via_app
    assert via_app["cfg"] == (run.module, run.item)  # the stage's own slice of params.yaml


@pytest.mark.parametrize("name", STAGES)
def test_main_reads_the_stages_deps_and_writes_its_outs(name, monkeypatch):
    """Every path ``main`` gets is a dependency or an output of the stage in ``dvc.yaml`` (so
    a change to it re-runs the stage), and every output lies in one of them."""
    run = one_run(name)
    given = paths_of(main_kwargs(run, monkeypatch))
    deps, outs = set(run.deps), set(run.outs)
    assert all(any(under(p, d) or under(d, p) for d in deps | outs) for p in given), (
        given, deps, outs)
    assert all(any(under(o, p) for p in given) for o in outs), (outs, given)


@pytest.mark.parametrize("name", STAGES)
def test_the_stage_defaults_are_dvc_yamls_paths(name, monkeypatch):
    """Without its path flags the stage hands ``main`` the same paths (``cmal_lcd.paths.REPO``
    gives the defaults): ``python -m cmal_lcd.stages.<x>`` alone works on the repository."""
    run = one_run(name)
    bare = ["--params", "params.yaml"] + (list(run.argv[-2:]) if run.item is not None else [])
    assert main_kwargs(run, monkeypatch, bare) == main_kwargs(run, monkeypatch)


@pytest.mark.parametrize("name", STAGES)
def test_root_moves_every_path_of_the_stage_under_it_and_nothing_else(name, monkeypatch,
                                                                       tmp_path):
    """``--root <job>`` (how the app runs a stage) hands ``main`` the same call with every
    path under the job folder; the working directory is not changed, so the config's own
    relative paths still mean the launch folder's."""
    run = one_run(name)
    here = main_kwargs(run, monkeypatch)
    cwd = Path.cwd()
    there = main_kwargs(run, monkeypatch, [*run.argv, "--root", str(tmp_path)])
    assert Path.cwd() == cwd
    assert there.keys() == here.keys()
    for key, value in here.items():
        assert there[key] == (tmp_path / value if isinstance(value, Path) else value), key


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
    monkeypatch.setattr(app, "run_stage", lambda run, job_dir: runs.append((run.name, run.item)))
    return runs


def test_run_chain_runs_every_step_in_dvc_yamls_order(tmp_path, monkeypatch):
    runs = record_runs(monkeypatch)
    cfg = compose(["debug=tiny", "methods=[sad,cmal_untrained]",
                   "app.steps=[report,evaluate,calibrate_world,dataset,train]"],
                  config_name="app")
    assert run_chain(cfg, tmp_path) == {}
    assert runs == [("dataset", None), ("calibrate_world", None), ("train", "cmal"),
                    ("evaluate", "sad"), ("evaluate", "cmal_untrained"), ("report", None)]
    # the stages read the job's params.yaml: the config without the app node
    from cmal_lcd.config import load_params

    params = load_params(tmp_path / "params.yaml")
    assert "app" not in params and list(params.methods) == ["sad", "cmal_untrained"]


def test_run_chain_skips_the_stages_of_reused_folders_and_links_them(tmp_path, monkeypatch):
    runs = record_runs(monkeypatch)
    for folder in ("d", "m", "old/features", "old/timing"):
        (tmp_path / folder).mkdir(parents=True)
    cfg = compose(["debug=tiny", "methods=[sad]", f"app.reuse.dataset={tmp_path / 'd'}",
                   f"app.reuse.models={tmp_path / 'm'}",
                   f"app.reuse.features={tmp_path / 'old/features'}"], config_name="app")
    run_chain(cfg, tmp_path / "job")
    assert [name for name, _ in runs] == [s for s in STAGES
                                          if s not in ("dataset", "train", "extract_features")]
    job = tmp_path / "job"
    assert (job / "data/dataset").resolve() == (tmp_path / "d").resolve()
    assert (job / "models").resolve() == (tmp_path / "m").resolve()
    assert (job / "data/timing").resolve() == (tmp_path / "old/timing").resolve()


def test_an_unknown_step_names_dvc_yamls_stages(tmp_path):
    cfg = compose(["debug=tiny", "app.steps=[evaluate,score]"], config_name="app")
    with pytest.raises(ValueError, match=r"app.steps: unknown steps \['score'\]; choose from"):
        run_chain(cfg, tmp_path)


def test_calibrate_world_says_why_a_folder_dataset_has_no_world():
    assert world_note(compose(["debug=tiny"])) is None
    cfg = compose(["debug=tiny"])
    cfg.data = {"kind": "folders"}
    assert "no world to calibrate" in world_note(cfg)
