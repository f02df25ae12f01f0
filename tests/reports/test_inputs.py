"""The report's file readers: required files fail naming the file, optional ones come back None."""

from __future__ import annotations

import json
import sys
from functools import partial
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from cmal_lcd.reports import inputs
from cmal_lcd.reports.reconstructions import EXAMPLE_KEYS

sys.path.insert(0, str(Path(__file__).parents[1] / "models"))
from model_helpers import write_model_file  # noqa: E402
from test_reconstructions import CONDITIONS, write_dataset  # noqa: E402

METRICS = {"auc_pr": 0.5, "auc_roc": 0.6, "recall_at_100p": 0.1, "recall_at_1": 0.2,
           "single_frame_recall_at_1": 0.3}


def write_json(path: Path, value) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(value))
    return path


def run_files(tmp_path: Path, *, methods=("sad", "cmal"), dataset_meta=None) -> inputs.RunFiles:
    """metrics, info and protocol files of ``methods`` on two pairs of one route."""
    for i, method in enumerate(methods):
        write_json(tmp_path / "evaluation" / method / "metrics.json",
                   {"route1": {pair: {"selected": {**METRICS, "auc_pr": i / 10},
                                      "paper": METRICS}
                               for pair in ("foggy-rainy", "rainy-sunny")}})
        write_json(tmp_path / "features" / method / "info.json",
                   {"label": method.upper()})
        write_json(tmp_path / "protocol" / f"{method}.json", {"selected": {"label": "x"}})
    if dataset_meta is not None:
        write_json(tmp_path / "dataset" / "dataset.json", dataset_meta)
    return inputs.read_run(evaluation_dir=tmp_path / "evaluation",
                           features_dir=tmp_path / "features", protocol_dir=tmp_path / "protocol",
                           dataset_dir=tmp_path / "dataset", methods=list(methods))


def test_read_json_names_the_missing_file_and_its_stage(tmp_path):
    with pytest.raises(FileNotFoundError, match=r"x\.json: missing; run the evaluate@sad stage"):
        inputs.read_json(tmp_path / "x.json", producer="evaluate@sad")
    (tmp_path / "bad.json").write_text("{")
    with pytest.raises(ValueError, match=r"bad\.json: not valid JSON"):
        inputs.read_json(tmp_path / "bad.json", producer="evaluate@sad")


def test_read_run_gives_labels_pair_order_conditions_and_nested_metrics(tmp_path):
    meta = {"kind": "k", "conditions": ["foggy", "rainy", "sunny"],
            "pairs": [["route1", "r/rainy", "r/sunny", "rainy-sunny"],
                      ["route1", "r/foggy", "r/rainy", "foggy-rainy"]]}
    run = run_files(tmp_path, dataset_meta=meta)
    assert run.methods == ["sad", "cmal"]
    assert run.labels == {"sad": "SAD", "cmal": "CMAL"}
    assert run.pair_order == [("route1", "rainy-sunny"), ("route1", "foggy-rainy")]
    assert run.conditions == ["foggy", "rainy", "sunny"]
    assert run.protocols["cmal"] == {"selected": {"label": "x"}}
    selected = run.nested_metrics("selected")
    assert list(selected["route1"]) == ["rainy-sunny", "foggy-rainy"]  # dataset.json's order
    assert selected["route1"]["foggy-rainy"]["cmal"]["auc_pr"] == pytest.approx(0.1)
    assert run.nested_metrics("paper")["route1"]["foggy-rainy"]["sad"]["auc_pr"] == 0.5


def test_without_dataset_json_there_is_no_pair_order_or_conditions(tmp_path):
    run = run_files(tmp_path)
    assert run.dataset_meta is None and run.pair_order == [] and run.conditions is None


def test_an_info_without_label_is_an_error_naming_it(tmp_path):
    write_json(tmp_path / "sad" / "info.json", {"method": "sad"})
    with pytest.raises(ValueError, match=r"sad/info\.json: no 'label'"):
        inputs.read_infos(tmp_path, ["sad"])


def test_pr_curves_are_nested_route_pair_method_and_need_recall_and_precision(tmp_path):
    for method in ("sad", "cmal"):
        path = tmp_path / method / "pr" / "route1" / "foggy-rainy.csv"
        path.parent.mkdir(parents=True)
        pd.DataFrame({"recall": [0.0, 1.0], "precision": [1.0, 0.5],
                      "threshold": [0, 1]}).to_csv(path, index=False)
    curves = inputs.read_pr_curves(tmp_path, pairs=[("route1", "foggy-rainy")],
                                   methods=["sad", "cmal"])
    assert list(curves["route1"]["foggy-rainy"]) == ["sad", "cmal"]
    assert curves["route1"]["foggy-rainy"]["cmal"]["precision"].tolist() == [1.0, 0.5]
    pd.DataFrame({"recall": [0.0]}).to_csv(tmp_path / "bad.csv", index=False)
    with pytest.raises(ValueError, match=r"bad\.csv: missing columns \['precision'\]"):
        inputs.read_pr_curve(tmp_path / "bad.csv")
    with pytest.raises(FileNotFoundError, match="evaluate stage"):
        inputs.read_pr_curve(tmp_path / "none.csv")


def test_pair_matrices_list_what_was_found_and_what_is_absent(tmp_path):
    path = tmp_path / "cmal" / "matrices" / "route1" / "foggy-rainy.npz"
    path.parent.mkdir(parents=True)
    np.savez(path, D=np.ones((3, 2), np.float32), match=np.array([0, -1]), other=np.zeros(1))
    read = inputs.read_pair_matrices(tmp_path, route="route1", pair="foggy-rainy",
                                     methods=["sad", "cmal"])
    assert (read.route, read.pair) == ("route1", "foggy-rainy")
    assert sorted(read.found["cmal"]) == ["D", "match"]  # only the keys Fig. 6 draws
    assert read.absent == [str(tmp_path / "sad" / "matrices" / "route1" / "foggy-rainy.npz")]


def test_pair_matrices_are_read_only_when_iterated(tmp_path):
    matrices = inputs.iter_pair_matrices(tmp_path, pairs=[("route1", "foggy-rainy")],
                                         methods=["cmal"])
    path = tmp_path / "cmal" / "matrices" / "route1" / "foggy-rainy.npz"
    path.parent.mkdir(parents=True)
    np.savez(path, D=np.ones((2, 2)))  # written after the iterator was made
    assert [list(m.found) for m in matrices] == [["cmal"]]


def test_reconstructions_are_computed_from_the_cmal_model_and_the_dataset(tmp_path):
    models = tmp_path / "models"
    dataset = write_dataset(tmp_path / "dataset")
    no_model = ("`models/cmal/model.pt` does not exist (no trained CMAL model in "
                "this run).")
    compute = partial(inputs.compute_reconstructions, models, heldout_fraction=0.25, seed=0,
                      dataset_missing="no dataset here.")
    assert compute(None) == (None, no_model)  # the model is named first
    assert compute(dataset) == (None, no_model)
    write_model_file(models, "cmal", conditions=CONDITIONS)
    assert compute(None) == (None, "no dataset here.")
    arrays, missing = compute(dataset)
    assert missing is None
    assert list(arrays) == list(EXAMPLE_KEYS) and len(arrays["frame_a"]) == 6


def test_train_logs_are_read_for_the_models_that_have_one(tmp_path):
    paths = inputs.train_log_paths(tmp_path, ["cmal", "bigan"])
    assert paths == {"cmal": tmp_path / "cmal" / "train_log.csv",
                     "bigan": tmp_path / "bigan" / "train_log.csv"}
    paths["bigan"].parent.mkdir()
    pd.DataFrame({"iteration": [0, 10], "D/loss": [1.0, 0.5]}).to_csv(paths["bigan"],
                                                                       index=False)
    logs = inputs.read_train_logs(paths)
    assert list(logs) == ["bigan"] and logs["bigan"]["D/loss"].tolist() == [1.0, 0.5]


def test_figure_dataset_says_which_files_are_missing(tmp_path):
    (tmp_path / "dataset.json").write_text("{}")
    dataset, missing = inputs.read_figure_dataset(tmp_path)
    assert dataset is None
    assert missing == f"`{tmp_path}` has no images.npy, frames.csv."


def test_optional_files_of_an_empty_run_are_all_absent(tmp_path):
    optional = inputs.read_optional(evaluation_dir=tmp_path / "evaluation",
                                    models_dir=tmp_path / "models",
                                    dataset_dir=tmp_path / "dataset",
                                    pairs=[("route1", "foggy-rainy")], methods=["sad"],
                                    model_names=["cmal"], heldout_fraction=0.25, seed=0)
    assert optional.invariance is None
    assert optional.invariance_path == tmp_path / "evaluation" / "invariance.json"
    assert optional.train_logs == {}
    assert list(optional.train_log_paths) == ["cmal"]
    assert optional.reconstructions is None and optional.dataset is None
    assert optional.reconstructions_missing == (
        "`models/cmal/model.pt` does not exist (no trained CMAL model in "
        "this run).")
    assert "has no dataset.json, images.npy, frames.csv" in optional.dataset_missing
    assert [m.found for m in optional.matrices] == [{}]
