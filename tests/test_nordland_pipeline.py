"""Real data end to end: Nordland summer/winter through every stage, at tiny size.

``experiment=nordland`` with ``debug=tiny`` model sizes, 40 training places per season and 40
test places (summer = reference, winter = query), chosen so both splits hold tunnel (near-black)
frames. Each stage function runs in a temporary folder. Skips with the reason when
``../shared/data/nordland_summer_winter`` is absent.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from cmal_lcd.config import compose
from cmal_lcd.data.folders import dark_frame_mask, main_folders
from cmal_lcd.data.store import load_dataset
from cmal_lcd.reports.reconstructions import reconstruction_examples

pytestmark = pytest.mark.nordland

METRICS = ("auc_pr", "auc_roc", "recall_at_100p", "recall_at_1", "single_frame_recall_at_1")
# debug=tiny keeps Nordland's own 32x64 frames (conf/debug/data/tiny_nordland.yaml) and touches
# no world-only key, so the experiment composes with it as it is.
TINY = ["experiment=nordland", "debug=tiny", "data.train.range=[1,40]",
        "data.validation.range=[1001,1040]", "data.test.range=[1201,1240]"]


def finite_everywhere(value) -> bool:
    if isinstance(value, dict):
        return all(finite_everywhere(v) for v in value.values())
    if isinstance(value, list):
        return all(finite_everywhere(v) for v in value)
    if isinstance(value, float):
        return math.isfinite(value)
    return True


@pytest.fixture(scope="module")
def run(nordland_dir, tmp_path_factory):
    """The whole chain on tiny Nordland; returns (cfg, run folder)."""
    from cmal_lcd.stages import (analyse_codes, evaluate, evaluate_loops, extract_features,
                                 report, select_protocol, train)

    root = tmp_path_factory.mktemp("nordland")
    cfg = compose(TINY + [f"data.train.dir={nordland_dir}", f"data.test.dir={nordland_dir}"])
    dataset = main_folders(cfg, out_dir=root / "data" / "dataset", min_conditions=2)
    for name in cfg.model_names:
        train.main(cfg, model_name=name, dataset_dir=dataset, out_dir=root / "models" / name,
                   checkpoints_dir=root / "checkpoints" / name, device="cpu")
    for method in cfg.methods:
        extract_features.main(cfg, method=method, dataset_dir=dataset,
                              models_dir=root / "models",
                              out_dir=root / "data" / "features" / method)
        select_protocol.main(cfg, method=method, dataset_dir=dataset,
                             features_dir=root / "data" / "features" / method,
                             out_path=root / "data" / "protocol" / f"{method}.json")
        evaluate.main(cfg, method=method, dataset_dir=dataset,
                      features_dir=root / "data" / "features" / method,
                      protocol_path=root / "data" / "protocol" / f"{method}.json",
                      out_dir=root / "data" / "evaluation" / method)
        evaluate_loops.main(cfg, method=method, dataset_dir=dataset,
                            features_dir=root / "data" / "features" / method,
                            protocol_path=root / "data" / "protocol" / f"{method}.json",
                            out_dir=root / "data" / "evaluation_loops" / method)
    analyse_codes.main(cfg, dataset_dir=dataset, features_dir=root / "data" / "features",
                       protocol_dir=root / "data" / "protocol", models_dir=root / "models",
                       out_path=root / "data" / "evaluation" / "invariance.json")
    report.main(cfg, evaluation_dir=root / "data" / "evaluation",
                features_dir=root / "data" / "features", models_dir=root / "models",
                dataset_dir=dataset, protocol_dir=root / "data" / "protocol",
                loops_dir=root / "data" / "evaluation_loops", out_dir=root / "reports",
                repo_dir=root)
    return cfg, root


def test_the_experiment_config_selects_the_nordland_folders_with_disjoint_splits():
    cfg = compose(["experiment=nordland"])
    assert cfg.data.kind == "folders"
    assert list(cfg.data.conditions) == ["summer", "winter"]
    assert list(cfg.data.train.range) == [1, 1000]
    assert list(cfg.data.validation.range) == [1001, 1200]
    assert cfg.data.test.range[0] == 1201
    assert cfg.data.test.reference == "summer" and cfg.data.test.query == "winter"


def test_the_tiny_dataset_has_two_seasons_one_pair_and_tunnel_frames_in_both_splits(run):
    _, root = run
    dataset = load_dataset(root / "data" / "dataset")
    assert dataset.meta["kind"] == "folders" and dataset.meta["ground_truth"] == "index"
    assert dataset.conditions == ["summer", "winter"]
    assert dataset.meta["pairs"] == [["nordland", "nordland/summer", "nordland/winter",
                                      "summer-winter"]]
    assert list(dataset.images.shape[1:]) == [32, 64, 3]
    counts = dataset.frames.groupby(["split", "condition"]).size().to_dict()
    assert counts == {("train", "summer"): 40, ("train", "winter"): 40,
                      ("val", "summer"): 40, ("val", "winter"): 40,
                      ("test", "summer"): 40, ("test", "winter"): 40}
    assert dataset.meta["validation_pairs"] == [["nordland_val", "nordland_val/summer",
                                                 "nordland_val/winter", "summer-winter"]]
    dark = dark_frame_mask(dataset.images)
    split = dataset.frames["split"].to_numpy()
    assert dark[split == "train"].any() and dark[split == "test"].any()


def test_every_method_is_evaluated_with_finite_metrics_despite_tunnels(run):
    cfg, root = run
    for method in cfg.methods:
        metrics = json.loads((root / "data" / "evaluation" / method / "metrics.json").read_text())
        for variant in ("selected", "paper"):
            values = metrics["nordland"]["summer-winter"][variant]
            for key in METRICS:
                if key == "auc_roc" and values[key] is None:
                    # ROC is undefined (null, shown as "–") only when every scored match is
                    # correct: there is no negative to rank.
                    assert values["recall_at_1"] * values["n_positive"] == values["n_scored"]
                    continue
                assert math.isfinite(values[key]), (method, variant, key, values[key])
            assert values["n_query"] == 40


def test_the_report_and_the_code_analysis_hold_no_nan(run):
    cfg, root = run
    report_metrics = json.loads((root / "reports" / "metrics.json").read_text())
    assert set(report_metrics["nordland"]["summer-winter"]) == set(cfg.methods)
    assert finite_everywhere(report_metrics)  # undefined values are null, never NaN
    invariance = json.loads((root / "data" / "evaluation" / "invariance.json").read_text())
    assert set(invariance) == {"nordland"}
    assert finite_everywhere(invariance)
    tables = list((root / "reports").rglob("*.md")) + list((root / "reports").rglob("*.csv"))
    assert tables
    for table in tables:
        assert "nan" not in table.read_text().lower().replace("nordland", ""), table


def test_the_reconstruction_figure_pairs_each_frame_with_the_same_place(run):
    cfg, root = run
    recon = reconstruction_examples(root / "models", load_dataset(root / "data" / "dataset"),
                                    heldout_fraction=cfg.models.cmal.heldout_fraction,
                                    seed=cfg.seed)
    # training rows: 40 summer places then the same 40 places in winter
    assert np.array_equal(recon["frame_b"] % 40, recon["frame_a"] % 40)
    assert (recon["condition_a"] != recon["condition_b"]).all()
    assert (root / "reports" / "figures" / "fig11_reconstructions.png").is_file()


def test_the_report_scores_every_row_again_at_the_strict_tolerance(run):
    cfg, root = run
    assert cfg.matching.d_thresh_strict == 2 < cfg.matching.d_thresh
    assert {"cmal_place", "place_encoder"} <= set(cfg.methods)
    for method in cfg.methods:
        pair = json.loads((root / "data" / "evaluation" / method / "metrics.json").read_text())[
            "nordland"]["summer-winter"]
        assert pair["strict"]["d_thresh"] == 2, method
        # the same matches, a stricter count: never more right
        for key in ("recall_at_1", "single_frame_recall_at_1", "recall_at_100p"):
            assert pair["strict"][key] <= pair["selected"][key], (method, key)
    readme = (root / "reports" / "README.md").read_text()
    assert "At a strict tolerance (±2 frames)" in readme
    assert (root / "reports" / "tables" / "strict_tolerance.csv").is_file()


def test_a_folder_dataset_has_no_looping_route_and_the_report_says_so(run):
    cfg, root = run
    for method in cfg.methods:
        record = json.loads((root / "data" / "evaluation_loops" / method / "metrics.json")
                            .read_text())
        assert record["skipped"].startswith("no looping route in this dataset")
    readme = (root / "reports" / "README.md").read_text()
    assert "Not produced in this run: no looping route in this dataset" in readme


def test_fig1_of_paired_folders_reads_without_overlaps(run):
    """Issue 37: Nordland's Fig. 1 had its title over the column titles and its row labels
    over each other."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parent / "reports"))
    from figure_checks import (assert_axis_labels_do_not_overlap,
                               assert_text_inside_the_figure, drawn)

    from cmal_lcd.reports.world_figures import weather_samples_figure

    _, root = run
    fig = weather_samples_figure(load_dataset(root / "data" / "dataset"))
    assert_axis_labels_do_not_overlap(fig)
    assert_text_inside_the_figure(fig)
    drawn(fig)
    renderer = fig.canvas.get_renderer()
    title = fig._suptitle.get_window_extent(renderer)
    assert all(title.y0 >= ax.title.get_window_extent(renderer).y1 - 1 for ax in fig.axes)
