"""Every params key a DVC stage reads is declared on it.

- The keys a stage's ``main`` gets (:func:`cmal_lcd.stages.stage_params`: its params in
  dvc.yaml, read by :func:`cmal_lcd.chain.declared_params`) are exactly its params as DVC
  resolves dvc.yaml (tests/dvc_stages.py), for every stage and matrix item.
- Reads are recorded, not guessed: each stage's ``main`` runs on a tiny dataset with the
  composed ``debug=tiny`` config while every leaf read from the config (attribute, item,
  ``get``, ``select``, ``to_container``, iteration of a list) is recorded. Each key read must be
  among the stage's params, or its ``NOT_INPUTS`` with the reason it cannot change the
  stage's outputs; then the slice ``main`` gets (:func:`cmal_lcd.stages.config_slice`) holds
  every value it reads, and a default can never stand in for a missing key.
"""

from __future__ import annotations

import importlib
import json
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from omegaconf import DictConfig, OmegaConf

from dvc_stages import ROOT, declares, resolved



def stage_module(name: str):
    """The ``cmal_lcd.stages`` module of DVC stage ``name`` (``evaluate@sad``) and its item."""
    from cmal_lcd.chain import stage_module as module_of

    base, _, item = name.partition("@")
    return importlib.import_module(module_of(ROOT / "dvc.yaml", base)), item or None


CONDITIONS = ["sunny", "foggy", "rainy"]
N_PLACES = 8


@pytest.fixture(scope="module")
def pipeline(tmp_path_factory):
    """dvc.yaml resolved with every built-in method and every model they read (the default
    config leaves the extensions out)."""
    from cmal_lcd.config import compose
    from cmal_lcd.features import METHOD_NAMES

    cfg = compose([f"methods=[{','.join(METHOD_NAMES)}]",
                   f"model_names=[{','.join(trained_models())}]"])
    return resolved(tmp_path_factory.mktemp("dvc"), params_yaml=OmegaConf.to_yaml(cfg))


def trained_models() -> list[str]:
    """The models the built-in methods read, each once."""
    from cmal_lcd.features import method_model, method_names

    return list(dict.fromkeys(m for m in map(method_model, method_names()) if m))


# ------------------------------------------------------------------------- recorded reads

def _key_of(node) -> str:
    """Dotted key of a config node; a list element counts as a read of the whole list."""
    parts: list[str] = []
    while node is not None and node._get_parent() is not None:
        key = node._metadata.key
        if isinstance(key, int):
            parts.clear()
        else:
            parts.append(str(key))
        node = node._get_parent()
    return ".".join(reversed(parts))


def _root_of(node):
    while node._get_parent() is not None:
        node = node._get_parent()
    return node


@contextmanager
def recording(root: DictConfig | None = None):
    """Record the dotted keys of every leaf (or list) read from any DictConfig, or only from
    ``root`` and its nodes (the stage's config, not a schema object the code builds to
    validate a part of it)."""
    reads: set[str] = set()
    original = DictConfig._get_node

    def _get_node(self, key, *args, **kwargs):
        node = original(self, key, *args, **kwargs)
        if node is not None and not isinstance(node, DictConfig) and (
                root is None or _root_of(node) is root):
            reads.add(_key_of(node))
        return node

    DictConfig._get_node = _get_node
    try:
        yield reads
    finally:
        DictConfig._get_node = original


def exempt(stage: str, key: str) -> bool:
    """Whether ``key`` is one of the stage module's ``NOT_INPUTS`` (or under one)."""
    module, _ = stage_module(stage)
    return any(key == k or key.startswith(k + ".") for k in getattr(module, "NOT_INPUTS", {}))


def undeclared(stage, reads: set[str]) -> list[str]:
    return sorted(k for k in reads if not declares(stage, k) and not exempt(stage.name, k))


def outside_slice(name: str, reads: set[str]) -> list[str]:
    """Keys of ``reads`` that the slice of stage ``name`` lacks."""
    from cmal_lcd.stages import stage_keys

    keys = stage_keys(*stage_module(name), tiny_config())
    return sorted(k for k in reads
                  if keys is not None and not any(k == p or k.startswith(p + ".") for p in keys))


def write_dataset(out: Path) -> Path:
    """8 places x 3 weathers of training frames, one test pair, two validation drives."""
    out.mkdir(parents=True)
    rng = np.random.default_rng(0)
    patterns = rng.integers(0, 200, (N_PLACES, 16, 16, 3))
    rows, images = [], []

    def add(image, **row):
        images.append(np.clip(image, 0, 255))
        rows.append({"y": 0.0, "heading": 0.0, **row})

    for place in range(N_PLACES):
        for k, condition in enumerate(CONDITIONS):
            add(patterns[place] + 25 * k, split="train", route="", drive="", condition=condition,
                x=10.0 * place, time=0.0, s=np.nan)
    for split, route in (("test", "route1"), ("val", "val")):
        for k, condition in enumerate(CONDITIONS[:2]):
            for place in range(N_PLACES):
                add(patterns[place] + 25 * k + 3, split=split, route=route,
                    drive=f"{route}/{condition}", condition=condition, x=10.0 * place,
                    time=float(place), s=10.0 * place)
    np.save(out / "images.npy", np.stack(images).astype(np.uint8))
    frames = pd.DataFrame(rows)[["split", "route", "drive", "condition", "x", "y", "heading",
                                 "time", "s"]]
    frames.insert(0, "frame", np.arange(len(frames)))
    frames.to_csv(out / "frames.csv", index=False)
    (out / "dataset.json").write_text(json.dumps({
        "kind": "test", "image_size": [16, 16], "conditions": CONDITIONS, "routes": ["route1"],
        "pairs": [["route1", "route1/sunny", "route1/foggy", "sunny-foggy"]],
        "validation_pairs": [["val", "val/sunny", "val/foggy", "sunny-foggy"]], "config": {},
        # a looping route for evaluate_loops: lap 1 sunny, lap 2 foggy
        "loops": [["route1", "route1/sunny", "route1/foggy", "sunny-foggy"]],
        "loop_exclude_frames": 2}))
    return out


def tiny_config() -> DictConfig:
    """The composed ``debug=tiny`` config, shrunk further to 16-pixel frames."""
    from cmal_lcd.config import compose

    cfg = compose(["debug=tiny", "models.cmal.image_size=16", "models.bigan.image_size=16",
                   "models.cmal.iterations=2", "models.bigan.iterations=2",
                   "models.place_encoder.iterations=2",
                   "models.cmal.heldout_fraction=0.25", "models.bigan.heldout_fraction=0.25",
                   "features.timing.repeats=1", "features.timing.warmup=0",
                   "features.timing.n_frames=2", "features.train_frames_per_condition=4",
                   "features.dnn.layer_candidates=[block4,block7]",
                   "matching.ds=2", "matching.v_min=1.0", "matching.v_max=1.0",
                   "matching.d_thresh=1", "matching.protocol.enhance_windows=[2]"])
    return cfg


@pytest.fixture(scope="module")
def recorded_reads(tmp_path_factory) -> dict[str, set[str]]:
    """Stage name -> keys its ``main`` read, for train@*, extract_features@*,
    select_protocol@{sad,cmal}, evaluate@{sad,cmal}, evaluate_loops@{sad,cmal} and
    analyse_codes (one tiny run each)."""
    import torch

    from cmal_lcd.features import METHOD_NAMES
    from cmal_lcd.stages import (analyse_codes, evaluate, evaluate_loops, extract_features,
                                 select_protocol, train)

    torch.set_num_threads(1)
    tmp = tmp_path_factory.mktemp("reads")
    dataset = write_dataset(tmp / "dataset")
    cfg = tiny_config()
    reads: dict[str, set[str]] = {}
    for model in trained_models():
        with recording(cfg) as r:
            train.main(cfg, model_name=model, dataset_dir=dataset, out_dir=tmp / "models" / model,
                       checkpoints_dir=tmp / "checkpoints" / model)
        reads[f"train@{model}"] = r
    for method in METHOD_NAMES:
        with recording(cfg) as r:
            extract_features.main(cfg, method=method, dataset_dir=dataset,
                                  models_dir=tmp / "models", out_dir=tmp / "features" / method)
        reads[f"extract_features@{method}"] = r
    for method in ("sad", "cmal"):
        with recording(cfg) as r:
            select_protocol.main(cfg, method=method, dataset_dir=dataset,
                                 features_dir=tmp / "features" / method,
                                 out_path=tmp / "protocol" / f"{method}.json")
        reads[f"select_protocol@{method}"] = r
        with recording(cfg) as r:
            evaluate.main(cfg, method=method, dataset_dir=dataset,
                          features_dir=tmp / "features" / method,
                          protocol_path=tmp / "protocol" / f"{method}.json",
                          out_dir=tmp / "evaluation" / method)
        reads[f"evaluate@{method}"] = r
        with recording(cfg) as r:
            evaluate_loops.main(cfg, method=method, dataset_dir=dataset,
                                features_dir=tmp / "features" / method,
                                protocol_path=tmp / "protocol" / f"{method}.json",
                                out_dir=tmp / "evaluation_loops" / method)
        reads[f"evaluate_loops@{method}"] = r
    cfg.methods = ["sad", "cmal"]
    with recording(cfg) as r:
        analyse_codes.main(cfg, dataset_dir=dataset, features_dir=tmp / "features",
                           protocol_dir=tmp / "protocol", models_dir=tmp / "models",
                           out_path=tmp / "evaluation" / "invariance.json")
    reads["analyse_codes"] = r
    return reads


def test_the_recorder_sees_each_kind_of_read():
    cfg = OmegaConf.create({"a": {"b": 1, "c": [1, 2]}, "m": ["x"], "s": 3, "d": {"e": {"f": 1}},
                            "unread": 1})
    with recording() as reads:
        _ = cfg.a.b
        list(cfg.m)
        OmegaConf.to_container(cfg.d, resolve=True)
        cfg.get("s")
        OmegaConf.select(cfg, "a.c")
    assert reads == {"a.b", "m", "d.e.f", "s", "a.c"}


@pytest.mark.parametrize("overrides", [[], ["methods=[cmal_untrained,sad]"]])
def test_each_stage_reads_its_params_as_dvc_resolves_them(tmp_path, overrides):
    """What the stages read of dvc.yaml's params, for every matrix item, is DVC's reading."""
    from cmal_lcd.config import compose
    from cmal_lcd.stages import stage_params

    cfg = compose(overrides)
    pipeline = resolved(tmp_path, params_yaml=OmegaConf.to_yaml(cfg))
    for name, stage in pipeline.stages.items():
        params = stage_params(*stage_module(name), cfg)
        assert stage.params == (None if params is None else frozenset(params)), name


def test_a_stage_reading_a_key_outside_its_slice_fails_naming_the_key():
    from omegaconf.errors import ConfigAttributeError

    from cmal_lcd.config import compose
    from cmal_lcd.stages import config_slice, evaluate, stage_keys

    part = config_slice(compose([]), stage_keys(evaluate, "sad"))
    assert part.matching.ds == compose([]).matching.ds and set(part) == {"matching"}
    with pytest.raises(ConfigAttributeError, match="seed"):
        _ = part.seed


def test_every_params_key_a_stage_reads_is_declared_on_it(pipeline, recorded_reads):
    missing = {name: undeclared(pipeline.stages[name], reads)
               for name, reads in recorded_reads.items()}
    assert not any(missing.values()), f"read but not declared in dvc.yaml: {missing}"
    outside = {name: outside_slice(name, reads) for name, reads in recorded_reads.items()}
    assert not any(outside.values()), f"read but not in the stage's slice: {outside}"
    # the recording saw the reads that matter (a recorder that saw nothing would pass)
    assert "matching.sad.width" in recorded_reads["extract_features@sad"]
    assert "models.cmal.code_dim" in recorded_reads["extract_features@cmal_untrained"]
    assert "models.cmal.iterations" not in recorded_reads["extract_features@cmal"]
    assert "methods" in recorded_reads["analyse_codes"]
    assert "matching.d_thresh" in recorded_reads["evaluate_loops@sad"]


def test_removing_a_declared_key_from_a_scratch_dvc_yaml_is_noticed(tmp_path, recorded_reads):
    """The check itself: sad without its second params slot (``matching.sad``; the first is its
    node ``extractors.sad``; on a copy of dvc.yaml) fails it."""
    text = (ROOT / "dvc.yaml").read_text()
    old = "        - ${item.params.1}\n"
    assert text.count(old) == 1
    broken = resolved(tmp_path, dvc_yaml=text.replace(old, ""))
    missing = undeclared(broken.stages["extract_features@sad"],
                         recorded_reads["extract_features@sad"])
    assert missing and all(k.startswith("matching.sad.") for k in missing)


# ---------------------------------------------------------------------------- narrowness

def test_no_features_stage_declares_a_method_specific_node_it_never_reads(pipeline,
                                                                         recorded_reads):
    """Narrow: each features stage's own nodes (beyond those dvc.yaml lists for every
    method) are read by it."""
    from cmal_lcd.chain import read_stages

    common = {p for p in read_stages(ROOT / "dvc.yaml")[0]["extract_features"]["params"]
              if "${" not in p}
    assert "seed" in common
    for name, reads in recorded_reads.items():
        if not name.startswith("extract_features@"):
            continue
        for key in pipeline.stages[name].params - common:
            assert any(r == key or r.startswith(key + ".") for r in reads), \
                f"{name} declares {key} but never reads it"


def test_each_features_stage_depends_on_its_own_weights_only(pipeline):
    weights = {name: {d for d in stage.deps if d.startswith("models")}
               for name, stage in pipeline.stages.items() if name.startswith("extract_features@")}
    assert weights == {
        "extract_features@sad": set(), "extract_features@dnn": set(),
        "extract_features@dnn_head": set(), "extract_features@bigan": {"models/bigan/model.pt"},
        "extract_features@cmal": {"models/cmal/model.pt"},
        # the untrained control is encoded under the trained CMAL classifier
        "extract_features@cmal_untrained": {"models/cmal/model.pt"},
        "extract_features@cmal_place": {"models/cmal_place/model.pt"},
        "extract_features@place_encoder": {"models/place_encoder/model.pt"}}


def test_changing_cmal_iterations_reruns_only_the_cmal_chain(pipeline):
    """DVC's own graph: the stages declaring ``models.cmal.iterations`` and everything
    downstream of them."""
    key = "models.cmal.iterations"
    direct = {name for name, stage in pipeline.stages.items() if declares(stage, key)}
    invalidated = direct | {d for name in direct for d in pipeline.downstream[name]}
    cmal = {"train@cmal", "analyse_codes", "report"} | {
        f"{stage}@{method}" for stage in ("extract_features", "select_protocol", "evaluate",
                                          "evaluate_loops")
        for method in ("cmal", "cmal_untrained")}
    assert invalidated == cmal


def test_the_features_stages_follow_methods(tmp_path):
    """``feature_inputs`` is derived from ``methods`` at composition, so the features stages
    are those of ``methods``, in its order, with the same command as every other stage."""
    from cmal_lcd.config import compose

    cfg = compose(["methods=[cmal_untrained,sad]"])
    pipeline = resolved(tmp_path, params_yaml=OmegaConf.to_yaml(cfg))
    names = [n for n in pipeline.stages if n.startswith("extract_features@")]
    assert names == ["extract_features@cmal_untrained", "extract_features@sad"]
    assert pipeline.stages["extract_features@sad"].cmd == (
        "PYTHONPATH=src python -m cmal_lcd.stages.extract_features --params params.yaml "
        "--dataset data/dataset --models models")
    assert [str(out) for out in pipeline.stages["extract_features@sad"].outs] == [
        "data/features/sad", "data/timing/sad.json"]


# ------------------------------------------------------- the stages that make the world

@pytest.fixture(scope="module")
def world_reads(tmp_path_factory) -> dict[str, set[str]]:
    """Keys read by the ``dataset`` and ``calibrate_world`` stages on the ``debug=tiny``
    rendered world (the real stage functions; a few seconds of rendering)."""
    from cmal_lcd.config import compose
    from cmal_lcd.stages import calibrate_world, make_dataset

    tmp = tmp_path_factory.mktemp("world_reads")
    cfg = compose(["debug=tiny"])
    reads: dict[str, set[str]] = {}
    # only the stage's own config: DataConfig.from_config validates `data` against a structured
    # schema object holding every key (with its defaults), which is not a read of params
    with recording(root=cfg) as r:
        make_dataset.main(cfg, out_dir=tmp / "dataset", manifest=tmp / "manifest.csv")
    reads["dataset"] = r
    with recording(root=cfg) as r:
        calibrate_world.main(cfg, dataset_dir=tmp / "dataset", out_dir=tmp / "world")
    reads["calibrate_world"] = r
    return reads


def test_the_rendered_dataset_does_not_depend_on_the_thread_count(tmp_path):
    """Why ``runtime.render_threads`` is not an input of the dataset stage (its NOT_INPUTS)."""
    from cmal_lcd.config import compose
    from cmal_lcd.stages import make_dataset

    outputs = {}
    for threads in (1, 2):
        cfg = compose(["debug=tiny", f"runtime.render_threads={threads}"])
        out = make_dataset.main(cfg, out_dir=tmp_path / str(threads))
        outputs[threads] = {p.name: p.read_bytes() for p in sorted(out.iterdir())}
    assert outputs[1] == outputs[2] and "images.npy" in outputs[1]


def test_the_recorder_can_watch_one_config_only():
    watched, other = OmegaConf.create({"a": 1}), OmegaConf.create({"b": 2})
    with recording(root=watched) as reads:
        _ = watched.a, other.b
    assert reads == {"a"}


def test_the_world_stages_declare_every_params_key_they_read(pipeline, world_reads):
    missing = {name: undeclared(pipeline.stages[name], reads)
               for name, reads in world_reads.items()}
    assert not any(missing.values()), f"read but not declared in dvc.yaml: {missing}"
    outside = {name: outside_slice(name, reads) for name, reads in world_reads.items()}
    assert not any(outside.values()), f"read but not in the stage's slice: {outside}"
    assert any(k.startswith("data.") for k in world_reads["dataset"])
    assert "seed" in world_reads["dataset"]
    assert any(k.startswith("matching.") for k in world_reads["calibrate_world"])


def test_the_report_depends_on_the_whole_params_file():
    """The report writes the whole composed config beside its numbers (reports/config.yaml),
    so every key is an input of it: dvc.yaml declares ``params.yaml:`` without keys."""
    from dvc_stages import resolved as resolve_pipeline

    import tempfile

    with tempfile.TemporaryDirectory() as scratch:
        assert resolve_pipeline(Path(scratch)).stages["report"].params is None
