"""The report's sections, called directly on plain data: each writes its files under
``out_dir`` and returns README entries (or says why it could not)."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest

from cmal_lcd.reports import figures, inputs, sections
from cmal_lcd.reports.readme import Entry
from cmal_lcd.reports.sections import (choices, curves, entries, invariance, loops, matrices,
                                       reconstructions, results, training, world)

METHODS = ["sad", "cmal"]
LABELS = {"sad": "SAD", "cmal": "CMAL"}
PAIRS = [("route1", "foggy-rainy"), ("route1", "rainy-sunny")]


def metrics(value: float) -> dict:
    return {"auc_pr": value, "auc_roc": value, "recall_at_100p": value, "recall_at_1": value,
            "single_frame_recall_at_1": value}


def nested(offset: float = 0.0) -> dict:
    """``{route: {pair: {method: metrics}}}`` with distinct values."""
    out: dict = {}
    for i, (route, pair) in enumerate(PAIRS):
        for j, method in enumerate(METHODS):
            out.setdefault(route, {}).setdefault(pair, {})[method] = metrics(
                0.1 + 0.2 * i + 0.1 * j + offset)
    return out


PROTOCOLS = {m: {"selected": {"label": "centre+L2"}, "paper": {"label": "raw"},
                 "candidates": [{"label": "centre+L2", "mean_recall_at_100p": 0.7,
                                 "mean_auc_pr": 0.8},
                                {"label": "raw", "mean_recall_at_100p": 0.2,
                                 "mean_auc_pr": 0.3}]} for m in METHODS}
INFOS = {m: {"label": LABELS[m], "dim": 8, "dtype": "float32", "bytes_per_frame": 32,
             "timing": {"device": "cpu (test)", "batch1_ms": 1.5, "batched_ms": 0.25,
                        "batch_size": 4, "repeats": 3}} for m in METHODS}


def written(out_dir: Path, entry: Entry) -> list[Path]:
    assert entry.files and entry.missing is None
    paths = [out_dir / f for f in entry.files]
    assert all(p.is_file() and p.stat().st_size > 0 for p in paths)
    return paths


# ---------------------------------------------------------------------------------------------
# Tables
# ---------------------------------------------------------------------------------------------

def test_table_entry_writes_three_renderings_and_inlines_the_table_without_caption(tmp_path):
    rendered = {"md": "Caption.\n\n| a |\n|---|", "csv": "a\n", "tex": "\\begin{table}"}
    entry = entries.table_entry(rendered, tmp_path / "tables" / "t", tmp_path, title="T",
                                description="D")
    assert entry.files == ["tables/t.md", "tables/t.csv", "tables/t.tex"]
    assert entry.markdown == "| a |\n|---|"
    assert (tmp_path / "tables" / "t.md").read_text() == rendered["md"]


def test_result_tables_are_the_six_in_readme_order_each_written_three_ways(tmp_path):
    got = results.result_entries(tmp_path, selected=nested(), paper_setting=nested(0.05),
                                 protocols=PROTOCOLS, infos=INFOS, methods=METHODS,
                                 labels=LABELS, d_thresh=20)
    assert [Path(e.files[0]).stem for e in got] == [
        "protocol", "table2_recall_at_100p", "auc", "recall_at_k", "table3_inference",
        "ablation_paper_protocol"]
    for entry in got:
        assert [Path(f).suffix for f in written(tmp_path, entry)] == [".md", ".csv", ".tex"]
        assert entry.title and entry.description and "CMAL" in entry.markdown
    caption = (tmp_path / "tables" / "table2_recall_at_100p.md").read_text().split("\n\n")[0]
    assert caption.startswith("Table II: recall at 100% precision")


def test_table2_entry_shows_the_selected_values(tmp_path):
    entry = results.recall_at_100p_entry(tmp_path, nested(), methods=METHODS, labels=LABELS)
    table = pd.read_csv(tmp_path / "tables" / "table2_recall_at_100p.csv")
    ours = table[(table.method == "CMAL") & (table.source == "this run")].iloc[0]
    assert ours["route1/rainy-sunny"] == pytest.approx(0.4)
    assert "| CMAL | this run |" in entry.markdown


def test_inference_entry_names_the_device(tmp_path):
    entry = results.inference_entry(tmp_path, INFOS, methods=METHODS)
    assert "cpu (test)" in entry.markdown


def test_invariance_entry_or_the_missing_file(tmp_path):
    source = tmp_path / "invariance.json"
    missing = invariance.invariance_entry(tmp_path, None, source=source, methods=METHODS,
                                          labels=LABELS)
    assert missing.missing == (f"`{source}` does not exist (the code-invariance analysis did "
                               "not run).")
    assert not (tmp_path / "tables").exists()
    data = {"route1": {m: {"normalisation": "centre+L2", "same_place": 1.0, "other_place": 2.0,
                           "ratio": 0.5, "single_frame_recall_at_1": 0.6, "raw_ratio": 0.9,
                           "raw_single_frame_recall_at_1": 0.3} for m in METHODS}}
    entry = invariance.invariance_entry(tmp_path, data, source=source, methods=METHODS,
                                        labels=LABELS)
    assert entry.title == invariance.TITLE
    assert [Path(p).name for p in written(tmp_path, entry)] == [
        "invariance.md", "invariance.csv", "invariance.tex"]


def loop_metrics(method_offset: float) -> dict:
    """``evaluate_loops``'s metrics.json: two routes, a weather-change loop and the control."""
    return {route: {loop: {"recall_at_100p": 0.1 * r + method_offset + (0.5 if same else 0.0),
                           "auc_pr": 0.2 + method_offset}
                    for loop, same in (("sunny-rainy", False), ("sunny-sunny", True))}
            for r, route in enumerate(["route1", "route2"])}


def test_loops_entry_tabulates_every_route_and_loop_and_their_mean(tmp_path):
    got = loops.loops_entry(tmp_path, {"sad": loop_metrics(0.0), "cmal": loop_metrics(0.05)},
                            source=tmp_path / "loops", methods=METHODS, labels=LABELS)
    assert got.title == loops.TITLE and got.missing is None
    assert sorted(got.files) == ["tables/loops.csv", "tables/loops.md", "tables/loops.tex"]
    table = pd.read_csv(tmp_path / "tables" / "loops.csv")
    assert table["route"].tolist() == ["route1", "route1", "route2", "route2", "mean", "mean"]
    assert table["loop"].tolist()[-2:] == ["sunny then rainy (weather change)",
                                           "sunny then sunny (same weather)"]
    assert list(table.columns) == ["route", "loop", "SAD R@100P", "SAD AUC-PR", "CMAL R@100P",
                                       "CMAL AUC-PR"]
    mean = table.iloc[4]
    assert mean["SAD R@100P"] == pytest.approx(0.05) and mean["CMAL R@100P"] == pytest.approx(0.1)
    assert table.iloc[5]["SAD R@100P"] == pytest.approx(0.55)
    assert "| mean | sunny then rainy (weather change) | 5.0% |" in got.markdown


def test_loops_entry_says_why_without_results_or_looping_routes(tmp_path):
    missing = loops.loops_entry(tmp_path, {"sad": loop_metrics(0.0), "cmal": None},
                                source=tmp_path / "loops", methods=METHODS, labels=LABELS)
    assert "['cmal']" in missing.missing and "evaluate_loops" in missing.missing
    skipped = {"skipped": "no looping route in this dataset (kind 'folders')"}
    none = loops.loops_entry(tmp_path, {"sad": skipped, "cmal": skipped},
                             source=tmp_path / "loops", methods=METHODS, labels=LABELS)
    assert none.missing.startswith("no looping route in this dataset")
    assert not (tmp_path / "tables" / "loops.md").exists()


def test_choice_tables_only_for_a_layer_selection_and_logged_validation(tmp_path):
    assert choices.choice_entries(tmp_path, infos=INFOS, logs={
        "cmal": pd.DataFrame({"iteration": [0, 10], "D/loss": [1.0, 0.5]})}) == []
    selection = {"protocol": "centre+L2", "criterion": "recall_at_100p", "selected": "b2",
                 "candidates": [{"layer": "b1", "val/recall_at_100p": 0.1},
                                {"layer": "b2", "val/recall_at_100p": 0.3}]}
    log = pd.DataFrame({"iteration": [0, 10, 20], "val/recall_at_100p": [0.1, 0.5, 0.49]})
    got = choices.choice_entries(tmp_path, infos={"dnn": {"layer_selection": selection}},
                                 logs={"cmal": log})
    assert [e.title for e in got] == ["DNN layer and input size chosen on validation",
                                      "Where training flattens (iterations)"]
    assert "codes centre+L2" in (tmp_path / "tables" / "dnn_layer.md").read_text()
    assert "best mean recall_at_100p won" in got[0].description
    assert "| cmal |" in got[1].markdown



def test_the_pooled_heads_side_choice_gets_its_own_table(tmp_path):
    selection = {"protocol": "centre+L2", "criterion": "recall_at_100p", "selected": "head",
                 "image_size": 64,
                 "candidates": [{"layer": "head", "image_size": 128, "val/recall_at_100p": 0.1},
                                {"layer": "head", "image_size": 64, "val/recall_at_100p": 0.3}]}
    got = choices.choice_entries(tmp_path, infos={"dnn_head": {"layer_selection": selection}},
                                 logs={})
    assert [e.title for e in got] == ["DNN pooled head: input size chosen on validation"]
    table = (tmp_path / "tables" / "dnn_head_side.md").read_text()
    assert "| head, 64 px | 30.0% |" in table and "| yes |" in table.split("head, 64 px")[1]
    assert not (tmp_path / "tables" / "dnn_layer.md").exists()


# ---------------------------------------------------------------------------------------------
# Figures
# ---------------------------------------------------------------------------------------------

def test_world_figures_say_why_without_a_dataset(tmp_path):
    got = world.world_entries(tmp_path, None, missing="`data/dataset` has no images.npy.")
    assert [e.title for e in got] == [f.title for f in world.WORLD_FIGURES]
    assert all(e.missing == "`data/dataset` has no images.npy." for e in got)


def test_world_figures_draw_with_the_plotting_functions_and_no_map_off_the_world(tmp_path):
    def plot(dataset, path):
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        Path(path).write_bytes(b"figure")

    plotting = SimpleNamespace(plot_weather_samples=plot, plot_world_map=plot)
    dataset = SimpleNamespace(meta={"kind": "nordland"})
    fig1, world_map = (world.world_figure_entry(tmp_path, dataset, f, plotting)
                       for f in world.WORLD_FIGURES)
    assert fig1.files == ["figures/fig01_weather_samples.png",
                          "figures/fig01_weather_samples.pdf"]
    assert world_map.missing.startswith("the dataset is `nordland`, not the procedural world")
    absent = world.world_figure_entry(tmp_path, dataset, world.WORLD_FIGURES[0],
                                      SimpleNamespace())
    assert absent.missing == ("`cmal_lcd.reports.world_figures.plot_weather_samples` does not "
                              "exist.")


def small_matrices(seed: int) -> dict:
    rng = np.random.default_rng(seed)
    D = rng.uniform(0, 1, (12, 10)).astype(np.float32)
    return {"D": D, "D_hat": D - D.mean(), "match": rng.integers(-1, 12, 10),
            "truth": np.arange(10)}


def test_matrix_entry_draws_found_methods_and_names_absent_files(tmp_path):
    entry = matrices.matrix_entry(tmp_path, route="route1", pair="foggy-rainy",
                                  found={"cmal": small_matrices(0)}, absent=["sad.npz"],
                                  labels=LABELS)
    assert entry.title == "Fig. 6: difference and enhanced matrices, route1 foggy-rainy"
    assert entry.description.endswith(" Missing for: sad.npz.")
    assert entry.files == ["figures/fig06_matrices_route1_foggy-rainy.png",
                           "figures/fig06_matrices_route1_foggy-rainy.pdf"]
    written(tmp_path, entry)
    none = matrices.matrix_entry(tmp_path, route="route1", pair="rainy-sunny", found={},
                                 absent=["a.npz", "b.npz"], labels=LABELS)
    assert none.missing == ("no difference matrices were saved by the evaluate stage (a.npz, "
                            "b.npz)")


def test_matrix_entries_one_per_pair_in_order(tmp_path):
    pairs = [inputs.PairMatrices(route=r, pair=p, found={}, absent=["x"]) for r, p in PAIRS]
    got = matrices.matrix_entries(tmp_path, iter(pairs), labels=LABELS)
    assert [e.title.rsplit(", ", 1)[1] for e in got] == ["route1 foggy-rainy",
                                                         "route1 rainy-sunny"]


def pr_curve(seed: int) -> pd.DataFrame:
    rng = np.random.default_rng(seed)
    return pd.DataFrame({"recall": np.sort(rng.uniform(0, 1, 6)),
                         "precision": np.sort(rng.uniform(0.3, 1, 6))[::-1]})


def test_pr_figures_one_per_route_and_the_auc_bars(tmp_path):
    styles = figures.method_styles(METHODS)
    pr = {"route1": {p: {m: pr_curve(i) for i, m in enumerate(METHODS)} for _, p in PAIRS},
          "route2": {"foggy-rainy": {m: pr_curve(5) for m in METHODS}}}
    got = curves.pr_entries(tmp_path, pr, labels=LABELS, styles=styles)
    assert [e.title for e in got] == ["Figs. 8-9: precision-recall curves, route1",
                                      "Figs. 8-9: precision-recall curves, route2"]
    assert got[1].files == ["figures/fig08-09_pr_route2.png", "figures/fig08-09_pr_route2.pdf"]
    for entry in got:
        written(tmp_path, entry)
    bars = curves.auc_bars_entry(tmp_path, nested(), methods=METHODS, labels=LABELS,
                                 styles=styles)
    assert bars.files == ["figures/fig10_auc.png", "figures/fig10_auc.pdf"]
    written(tmp_path, bars)


def test_condition_names_from_indices_or_as_text():
    assert reconstructions.condition_names(np.array([0, 2, 7]), ["a", "b", "c"]) == \
        ["a", "c", "7"]
    assert reconstructions.condition_names(np.array([1]), None) == ["1"]
    assert reconstructions.condition_names(np.array(["rainy"]), ["a"]) == ["rainy"]


def test_reconstruction_entry_or_why_not(tmp_path):
    why = "`models/cmal/model.pt` does not exist (no trained CMAL model in this run)."
    missing = reconstructions.reconstruction_entry(tmp_path, None, missing=why, conditions=None)
    assert missing.title == reconstructions.TITLE
    assert missing.missing == why
    rng = np.random.default_rng(0)
    arrays = {k: rng.integers(0, 256, (2, 8, 12, 3), dtype=np.uint8)
              for k in ("a", "recon_a", "translated_b", "b")}
    entry = reconstructions.reconstruction_entry(
        tmp_path, {**arrays, "condition_a": np.array([0, 1]), "condition_b": np.array([1, 0])},
        missing=None, conditions=["sunny", "rainy"])
    assert entry.files == ["figures/fig11_reconstructions.png",
                           "figures/fig11_reconstructions.pdf"]
    written(tmp_path, entry)


def test_training_entries_follow_the_models_and_say_why_a_log_is_missing(tmp_path):
    sources = {name: tmp_path / name / "train_log.csv" for name in ("cmal", "bigan", "x")}
    logs = {"cmal": pd.DataFrame({"iteration": [0, 10], "D/loss": [1.0, 0.5],
                                  "val/auc_pr": [0.2, 0.4]}),
            "x": pd.DataFrame({"iteration": []})}
    cmal, bigan, empty = training.training_entries(tmp_path, logs, sources=sources)
    assert cmal.title == "Training curves: cmal"
    assert cmal.files == ["figures/training_cmal.png", "figures/training_cmal.pdf"]
    written(tmp_path, cmal)
    assert bigan.missing == f"`{sources['bigan']}` does not exist."
    assert empty.missing == f"`{sources['x']}` has no rows."


# ---------------------------------------------------------------------------------------------
# All sections, in README order
def test_the_strict_tolerance_table_follows_recall_at_k_only_when_every_pair_has_it(tmp_path):
    def evaluations(with_strict: bool) -> dict:
        out = {}
        for j, method in enumerate(METHODS):
            for route, pair in PAIRS:
                variants = {"selected": metrics(0.5 + 0.1 * j), "paper": metrics(0.4)}
                if with_strict:
                    variants["strict"] = {**metrics(0.2 + 0.1 * j), "d_thresh": 2}
                out.setdefault(method, {}).setdefault(route, {})[pair] = variants
        return out

    run = inputs.RunFiles(methods=METHODS, evaluations=evaluations(True), infos=INFOS,
                          protocols=PROTOCOLS, dataset_meta=None)
    strict, tolerance = run.strict_metrics()
    assert tolerance == 2 and strict["route1"]["foggy-rainy"]["cmal"]["recall_at_1"] == pytest.approx(0.3)
    got = results.result_entries(tmp_path, selected=nested(), paper_setting=nested(0.05),
                                 protocols=PROTOCOLS, infos=INFOS, methods=METHODS,
                                 labels=LABELS, d_thresh=20, strict=(strict, tolerance))
    stems = [Path(e.files[0]).stem for e in got]
    assert stems[stems.index("recall_at_k") + 1] == "strict_tolerance"
    entry = got[stems.index("strict_tolerance")]
    assert "±2 frames" in entry.title and "30.0" in entry.markdown
    table = (tmp_path / "tables" / "strict_tolerance.csv").read_text()
    assert "single-frame recall@1" in table
    half = evaluations(True)
    del half["sad"]["route1"]["rainy-sunny"]["strict"]
    for partial in (evaluations(False), half):
        assert inputs.RunFiles(methods=METHODS, evaluations=partial, infos=INFOS,
                               protocols=PROTOCOLS, dataset_meta=None).strict_metrics() is None


# ---------------------------------------------------------------------------------------------

def test_table_and_figure_entries_run_every_section_in_readme_order(tmp_path):
    run = inputs.RunFiles(methods=METHODS, evaluations={}, infos=INFOS, protocols=PROTOCOLS,
                          dataset_meta=None)
    optional = inputs.OptionalFiles(
        invariance=None, invariance_path=tmp_path / "invariance.json", train_logs={},
        train_log_paths={"cmal": tmp_path / "train_log.csv"}, selections={},
        reconstructions=None, reconstructions_missing="no CMAL model.", dataset=None,
        dataset_missing="no dataset here.",
        matrices=iter([inputs.PairMatrices("route1", "foggy-rainy", {}, ["x"])]))
    tables = sections.table_entries(tmp_path, run, optional, selected=nested(),
                                    paper_setting=nested(), d_thresh=20)
    assert [e.title for e in tables][-3:] == ["Ablation: the paper's protocol",
                                              invariance.TITLE, loops.TITLE]
    assert len(tables) == 8
    pr = {"route1": {p: {m: pr_curve(0) for m in METHODS} for _, p in PAIRS}}
    got = sections.figure_entries(tmp_path, run, optional, selected=nested(), pr_curves=pr)
    assert [e.title.split(":")[0] for e in got] == [
        "Fig. 1", "World map", "Fig. 6", "Figs. 8-9", "Fig. 10", "Fig. 11", "Training curves"]
    assert [e.missing is None for e in got] == [False, False, False, True, True, False, False]
    assert got[5].missing == "no CMAL model."  # Fig. 11 says why, in the inputs' words


def test_the_report_names_a_jobs_weights_relative_to_the_job(tmp_path):
    models = tmp_path / "outputs" / "job" / "models"
    infos = {"cmal": {"weights": f"trained cmal {models}/cmal/model.pt (iteration 250)"},
             "sad": {"weights": "none (grey thumbnails)"}}
    inputs.relative_weights(infos, models)
    assert infos["cmal"]["weights"] == "trained cmal models/cmal/model.pt (iteration 250)"
    assert infos["sad"]["weights"] == "none (grey thumbnails)"
