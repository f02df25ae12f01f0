"""Tables: built from the nested metrics, rendered as Markdown, LaTeX booktabs and CSV."""

import io
import math

import numpy as np
import pandas as pd
import pytest

from cmal_lcd.reports import render, tables
from cmal_lcd.reports.tables import METRIC_KEYS

LABELS = {"sad": "SAD", "dnn": "DNN (EfficientNet-Lite0)", "cmal": "CMAL",
          "cmal_untrained": "CMAL (untrained control)"}


def values(seed: float) -> dict:
    return {key: round(seed + 0.01 * i, 4) for i, key in enumerate(METRIC_KEYS)}


def evaluations(methods=("sad", "cmal"), pairs=(("route1", "foggy-rainy"),
                                                 ("route2", "foggy-sunny"))) -> dict:
    """``{method: {route: {pair: {variant: metrics}}}}``: selected = 0.1*k,
    paper_setting = 0.5 + ..."""
    out: dict = {}
    for m, method in enumerate(methods):
        for p, (route, pair) in enumerate(pairs):
            out.setdefault(method, {}).setdefault(route, {})[pair] = {
                "selected": {**values(0.1 * (m + 1) + 0.02 * p), "n_query": 9},
                "paper": values(0.5 + 0.1 * m + 0.02 * p)}
    return out


def nested(methods=("sad", "cmal"), **kw) -> dict:
    return tables.metrics_by_route_pair_method(evaluations(methods, **kw), methods=methods,
                                               variant="selected")


# --- reshaping ------------------------------------------------------------------------------

def test_regroups_route_pair_method_with_the_five_metrics_only():
    result = nested()
    assert list(result) == ["route1", "route2"]
    assert set(result["route1"]["foggy-rainy"]) == {"sad", "cmal"}
    assert result["route1"]["foggy-rainy"]["cmal"] == values(0.2)
    assert "n_query" not in result["route1"]["foggy-rainy"]["sad"]


def test_paper_variant_is_selected():
    paper_setting = tables.metrics_by_route_pair_method(evaluations(), methods=["sad"],
                                                        variant="paper")
    assert paper_setting["route2"]["foggy-sunny"]["sad"] == values(0.52)


def test_null_metric_becomes_nan():
    ev = evaluations(methods=("sad",))
    ev["sad"]["route1"]["foggy-rainy"]["selected"]["recall_at_100p"] = None
    result = tables.metrics_by_route_pair_method(ev, methods=["sad"], variant="selected")
    assert math.isnan(result["route1"]["foggy-rainy"]["sad"]["recall_at_100p"])


def test_pair_order_follows_the_given_order_grouped_by_route():
    pairs = (("route1", "a-b"), ("route2", "a-b"), ("route1", "c-d"))
    result = tables.metrics_by_route_pair_method(
        evaluations(("sad",), pairs=pairs), methods=["sad"], variant="selected",
        pair_order=[("route2", "a-b"), ("route1", "c-d"), ("route1", "a-b")])
    assert tables.route_pairs(result) == [("route2", "a-b"), ("route1", "c-d"), ("route1", "a-b")]


def test_pairs_not_in_the_given_order_follow_in_file_order():
    pairs = (("route1", "a-b"), ("route1", "c-d"))
    result = tables.metrics_by_route_pair_method(
        evaluations(("sad",), pairs=pairs), methods=["sad"], variant="selected",
        pair_order=[("route1", "c-d"), ("elsewhere", "x-y")])
    assert tables.route_pairs(result) == [("route1", "c-d"), ("route1", "a-b")]


def test_a_method_missing_a_pair_is_an_error_naming_it():
    ev = evaluations()
    del ev["cmal"]["route2"]
    with pytest.raises(ValueError, match="cmal.*route2/foggy-sunny"):
        tables.metrics_by_route_pair_method(ev, methods=["sad", "cmal"], variant="selected")


def test_a_missing_variant_or_metric_is_an_error():
    ev = evaluations()
    del ev["sad"]["route1"]["foggy-rainy"]["paper"]
    with pytest.raises(ValueError, match="sad.*paper"):
        tables.metrics_by_route_pair_method(ev, methods=["sad"], variant="paper")
    ev = evaluations()
    del ev["sad"]["route1"]["foggy-rainy"]["selected"]["auc_pr"]
    with pytest.raises(ValueError, match="auc_pr"):
        tables.metrics_by_route_pair_method(ev, methods=["sad"], variant="selected")


def test_an_unknown_method_is_an_error():
    with pytest.raises(ValueError, match="bigan"):
        tables.metrics_by_route_pair_method(evaluations(), methods=["bigan"], variant="selected")


# --- table contents -------------------------------------------------------------------------

def test_table2_puts_the_paper_row_under_each_method_the_paper_reports():
    methods = ["sad", "cmal", "cmal_untrained"]
    table = tables.recall_at_100p_table(nested(methods), methods=methods, labels=LABELS)
    assert list(table.index) == [("SAD", "this run"), ("SAD", "paper: SAD"),
                                 ("CMAL", "this run"), ("CMAL", "paper: CMAL"),
                                 ("CMAL (untrained control)", "this run")]
    assert list(table.columns) == [("route1", "foggy-rainy"), ("route2", "foggy-sunny")]
    assert table.loc[("CMAL", "this run"), ("route1", "foggy-rainy")] == pytest.approx(
        values(0.2)["recall_at_100p"])
    assert table.loc[("SAD", "paper: SAD"), ("route1", "foggy-rainy")] == pytest.approx(0.348)
    assert table.loc[("CMAL", "paper: CMAL"), ("route2", "foggy-sunny")] == pytest.approx(0.101)


def test_table2_paper_cells_are_empty_where_the_pair_is_not_the_papers():
    pairs = (("route1", "foggy-rainy"), ("route1", "sunny-foggy"))
    table = tables.recall_at_100p_table(nested(("sad",), pairs=pairs), methods=["sad"],
                                        labels=LABELS)
    paper_row = table.loc[("SAD", "paper: SAD")]
    assert paper_row[("route1", "foggy-rainy")] == pytest.approx(0.348)
    assert math.isnan(paper_row[("route1", "sunny-foggy")])


def test_table2_has_no_paper_rows_for_a_dataset_the_paper_did_not_use():
    pairs = (("nordland", "summer-winter"),)
    table = tables.recall_at_100p_table(nested(("sad", "cmal"), pairs=pairs),
                                        methods=["sad", "cmal"], labels=LABELS)
    assert set(table.index.get_level_values("source")) == {tables.THIS_RUN}


def test_dnn_paper_row_names_vgg16_while_ours_keeps_its_label():
    table = tables.recall_at_100p_table(nested(("dnn",)), methods=["dnn"], labels=LABELS)
    assert list(table.index) == [("DNN (EfficientNet-Lite0)", "this run"),
                                 ("DNN (EfficientNet-Lite0)", "paper: DNN (VGG16)")]


def test_auc_table_has_roc_and_pr_rows_per_method():
    table = tables.auc_table(nested(), methods=["sad", "cmal"], labels=LABELS)
    assert list(table.index) == [("SAD", "AUC-ROC"), ("SAD", "AUC-PR"),
                                 ("CMAL", "AUC-ROC"), ("CMAL", "AUC-PR")]
    assert table.loc[("CMAL", "AUC-PR"), ("route2", "foggy-sunny")] == pytest.approx(
        values(0.22)["auc_pr"])


def test_ablation_table_pairs_each_setting():
    ev = evaluations()
    selected = tables.metrics_by_route_pair_method(ev, methods=["sad"], variant="selected")
    paper_setting = tables.metrics_by_route_pair_method(ev, methods=["sad"], variant="paper")
    table = tables.ablation_table(selected, paper_setting, methods=["sad"], labels=LABELS,
                                  metrics=["recall_at_100p"])
    col = ("route1", "foggy-rainy")
    assert table.loc[("SAD", "recall@100%P", tables.VARIANT_LABELS["selected"]), col] == \
        pytest.approx(values(0.1)["recall_at_100p"])
    assert table.loc[("SAD", "recall@100%P", tables.VARIANT_LABELS["paper"]), col] == \
        pytest.approx(values(0.5)["recall_at_100p"])


def info(label, **timing):
    return {"label": label, "dim": 1024, "dtype": "float32", "bytes_per_frame": 4096,
            "timing": {"device": "cpu", "batch1_ms": 2.5, "batched_ms": 0.5, "batch_size": 32,
                       "repeats": 7, **timing}}


def test_inference_table_reads_timing_and_adds_the_papers_table3():
    infos = {"sad": info("SAD"), "dnn": info("DNN (EfficientNet-Lite0)", device="cuda:0")}
    table = tables.inference_table(infos, methods=["sad", "dnn"])
    assert list(table.index) == ["SAD", "DNN (EfficientNet-Lite0)"]
    assert list(table.columns) == list(tables.INFERENCE_COLUMNS)
    assert table.loc["SAD", "batch-1 ms/frame"] == 2.5
    assert table.loc["DNN (EfficientNet-Lite0)", "device"] == "cuda:0"
    assert table.loc["SAD", "paper ms/frame"] == "3.2–3.4"
    assert table.loc["DNN (EfficientNet-Lite0)", "paper ms/frame"] == ""


def test_inference_table_tolerates_missing_timing():
    table = tables.inference_table({"cmal": {"label": "CMAL"}}, methods=["cmal"])
    assert table.loc["CMAL", "device"] == "unknown"
    assert math.isnan(table.loc["CMAL", "batch-1 ms/frame"])


def test_invariance_table_skips_absent_methods_and_optional_accuracy():
    inv = {"route1": {"cmal": {"same_place_cross_condition": 1.0,
                               "different_place_same_condition": 4.0, "ratio": 0.25,
                               "classifier_accuracy": 0.9},
                      "sad": {"same_place_cross_condition": 3.0,
                              "different_place_same_condition": 2.0, "ratio": 1.5}}}
    table = tables.invariance_table(inv, methods=["sad", "dnn", "cmal"], labels=LABELS)
    assert list(table.index) == [("route1", "SAD"), ("route1", "CMAL")]
    assert table.loc[("route1", "CMAL"), "ratio"] == 0.25
    assert math.isnan(table.loc[("route1", "SAD"), "weather classifier accuracy"])


# --- rendering ------------------------------------------------------------------------------

@pytest.mark.parametrize("value, text", [(0.348, "34.8%"), (1.0, "100.0%"), (0.0, "0.0%"),
                                         (0.0014, "0.1%"), (math.nan, "–"), (None, "–")])
def test_percent_like_the_paper(value, text):
    assert render.format_percent(value) == text


@pytest.mark.parametrize("value, text", [(4096.0, "4,096"), (0.123456, "0.123"),
                                         (math.nan, "–")])
def test_number_format(value, text):
    assert render.format_number(value) == text


def table2():
    methods = ["sad", "cmal"]
    return tables.recall_at_100p_table(nested(methods), methods=methods, labels=LABELS)


def test_markdown_has_one_line_per_row_and_groups_repeated_labels():
    md = render.markdown_table(render.format_cells(table2()))
    lines = md.strip().split("\n")
    assert lines[0] == "| method | source | route1 foggy-rainy | route2 foggy-sunny |"
    assert lines[1] == "|:--|:--|--:|--:|"
    assert len(lines) == 2 + 4
    assert lines[2].startswith("| SAD | this run | ")
    assert lines[3].startswith("|  | paper: SAD | 34.8% |")  # repeated outer label left blank


def test_markdown_escapes_pipes_and_left_aligns_text_columns():
    table = pd.DataFrame({"device": ["a|b"], "ms": [1.0]}, index=pd.Index(["X"], name="method"))
    rendered = render.render_table(table, caption="c", label="l", default=render.format_ms)
    assert "a\\|b" in rendered["md"]
    assert "|:--|:--|--:|" in rendered["md"]


def test_latex_is_booktabs_with_grouped_route_header_and_escaped_percent():
    tex = render.latex_booktabs_table(render.format_cells(table2()), caption="Recall 100%",
                                      label="tab:x")
    assert tex.startswith("\\begin{table}")
    for rule in ("\\toprule", "\\midrule", "\\bottomrule"):
        assert tex.count(rule) == 1
    assert "\\caption{Recall 100\\%}" in tex
    assert "\\multicolumn{1}{c}{route1} & \\multicolumn{1}{c}{route2}" in tex
    assert "\\cmidrule(lr){3-3} \\cmidrule(lr){4-4}" in tex
    assert "34.8\\%" in tex
    assert "\\begin{tabular}{llrr}" in tex
    body = tex.split("\\midrule")[1].split("\\bottomrule")[0].strip().split("\n")
    assert len(body) == 4 and all(line.endswith("\\\\") for line in body)


def test_latex_escapes_special_characters():
    assert render.escape_latex("a_b & 5% #1 ~") == "a\\_b \\& 5\\% \\#1 \\textasciitilde{}"


def test_csv_holds_raw_floats_that_read_back_exactly():
    table = table2()
    table.iloc[0, 0] = np.nan
    text = render.csv_table(table)
    back = pd.read_csv(io.StringIO(text))
    assert list(back.columns) == ["method", "source", "route1/foggy-rainy", "route2/foggy-sunny"]
    np.testing.assert_array_equal(back.iloc[:, 2:].to_numpy(), table.to_numpy())
    assert "%" not in text


def test_render_and_write_three_files(tmp_path):
    rendered = render.render_table(table2(), caption="Table II.", label="tab:t2")
    assert set(rendered) == {"md", "csv", "tex"}
    assert rendered["md"].startswith("Table II.\n\n| method |")
    paths = render.write_table(rendered, tmp_path / "sub" / "table2_recall_at_100p")
    assert sorted(p.name for p in paths) == ["table2_recall_at_100p.csv",
                                             "table2_recall_at_100p.md",
                                             "table2_recall_at_100p.tex"]
    for path in paths:
        assert path.read_text() == rendered[path.suffix[1:]]
    assert not [p for p in (tmp_path / "sub").iterdir() if p.name.startswith(".tmp")]


def test_empty_text_cells_are_shown_as_missing():
    table = pd.DataFrame({"paper": [""]}, index=["X"])
    assert render.format_cells(table).iloc[0, 0] == render.MISSING


def test_method_summary_is_six_means_per_method_over_every_route_and_pair():
    nested = {"r1": {"a": {"sad": {"recall_at_100p": 0.2, "auc_pr": 0.5, "auc_roc": 0.9,
                                   "recall_at_1": 0.6, "recall_at_5": 0.7,
                                   "single_frame_recall_at_1": 0.3}},
                     "b": {"sad": {"recall_at_100p": 0.4, "auc_pr": float("nan"),
                                   "auc_roc": 0.7, "recall_at_1": 0.8,
                                   "single_frame_recall_at_1": 0.5}}}}
    summary = tables.method_summary(nested, methods=["sad"])
    # NaN and absent values are skipped: AUC-PR and R@5 are the one pair that has them
    assert summary == {"sad": {"R@100P": 0.3, "AUC-PR": 0.5, "AUC-ROC": 0.8, "R@1": 0.7,
                               "R@5": 0.7, "SF-R@1": 0.4}}


def test_method_summary_is_none_where_no_pair_has_a_value():
    nested = {"r1": {"a": {"sad": {"recall_at_100p": 0.2}}}}
    assert tables.method_summary(nested, methods=["sad"])["sad"]["R@5"] is None


def test_summary_rows_fit_a_100_column_dvc_metrics_show():
    """`dvc metrics show -R reports/summary` prints one row per method file: path, then one
    column per key, each as wide as the wider of its key and a 6-character value, four spaces
    apart."""
    path = "reports/summary/cmal_untrained.json"
    width = len(path) + sum(4 + max(len(key), 6) for key in tables.SUMMARY_KEYS)
    assert width <= 100
    assert len(tables.SUMMARY_KEYS) == 6


def test_recall_at_k_keys_are_kept_when_the_file_has_them_and_absent_otherwise():
    ev = evaluations(methods=("sad",))
    ev["sad"]["route1"]["foggy-rainy"]["selected"].update(recall_at_5=0.9,
                                                          single_frame_recall_at_20=None)
    result = tables.metrics_by_route_pair_method(ev, methods=["sad"], variant="selected")
    first = result["route1"]["foggy-rainy"]["sad"]
    assert first["recall_at_5"] == 0.9 and math.isnan(first["single_frame_recall_at_20"])
    assert "recall_at_5" not in result["route2"]["foggy-sunny"]["sad"]
    assert math.isnan(tables.metric_value(result, "route2", "foggy-sunny", "sad", "recall_at_5"))


def test_recall_at_k_table_has_sequence_and_single_frame_rows_with_means_over_pairs():
    nested = {"r1": {"a": {"sad": {"recall_at_1": 0.5, "recall_at_5": 0.6, "recall_at_10": 0.7,
                                   "recall_at_20": 0.8, "single_frame_recall_at_1": 0.1,
                                   "single_frame_recall_at_5": 0.2}},
                     "b": {"sad": {"recall_at_1": 0.7, "recall_at_5": 0.8,
                                   "single_frame_recall_at_1": 0.3}}}}
    table = tables.recall_at_k_table(nested, methods=["sad"], labels={"sad": "SAD"})
    assert list(table.columns) == ["R@1", "R@5", "R@10", "R@20"]
    assert list(table.index) == [("SAD", "sequence (SeqSLAM)"), ("SAD", "single frame")]
    np.testing.assert_allclose(table.loc[("SAD", "sequence (SeqSLAM)")], [0.6, 0.7, 0.7, 0.8])
    single = table.loc[("SAD", "single frame")].to_numpy()
    np.testing.assert_allclose(single[:2], [0.2, 0.2])
    assert np.isnan(single[2:]).all()  # no pair has them: "–" in the rendered table
    assert render.render_table(table, caption="c", label="l")["md"].count("–") == 2


def test_the_plateau_is_the_first_iteration_within_two_points_of_the_best():
    from cmal_lcd.reports.tables import plateau_iteration

    assert plateau_iteration([0, 50, 100, 150, 200], [0.1, 0.3, 0.49, 0.5, 0.45]) == 100
    assert plateau_iteration([0, 50, 100], [0.1, 0.2, 0.3]) == 100  # still rising: the end
    assert plateau_iteration([0, 50], [np.nan, 0.2]) == 50
    assert np.isnan(plateau_iteration([0, 50], [np.nan, np.nan]))


def test_validation_curve_table_reads_only_the_validation_rows_of_a_log():
    from cmal_lcd.reports.tables import validation_curve_table

    log = pd.DataFrame({"iteration": [0, 25, 50, 75, 100],
                        "D/loss": [np.nan, 1.0, 0.9, 0.8, 0.7],
                        "val/recall_at_100p": [0.2, np.nan, 0.6, np.nan, 0.5]})
    table = validation_curve_table({"cmal": log, "bigan": log.drop(columns="val/recall_at_100p")})
    assert list(table.index) == ["cmal"]
    assert table.loc["cmal"].tolist()[:6] == [0.2, 0.6, 50.0, 0.5, 100.0, 50.0]
    assert np.isnan(table.loc["cmal", "model.pt keeps iteration"])  # no selection.json


def test_validation_curve_table_says_which_iteration_model_pt_keeps():
    from cmal_lcd.reports.tables import validation_curve_table

    log = pd.DataFrame({"iteration": [0, 50, 100], "val/recall_at_100p": [0.2, 0.6, 0.5]})
    table = validation_curve_table({"cmal": log}, selections={"cmal": {"iteration": 50}})
    assert table.loc["cmal", "model.pt keeps iteration"] == 50.0


def test_layer_choice_table_marks_the_chosen_layer():
    from cmal_lcd.reports.tables import layer_choice_table

    table = layer_choice_table({"selected": "block7", "candidates": [
        {"layer": "block4", "val/recall_at_100p": 0.1, "val/auc_pr": 0.2,
         "val/single_frame_recall_at_1": 0.3},
        {"layer": "block7", "val/recall_at_100p": 0.5, "val/auc_pr": 0.6,
         "val/single_frame_recall_at_1": 0.7}]})
    assert table["chosen"].tolist() == ["", "yes"]
    assert table.loc["block7", "validation R@100P"] == 0.5


def test_layer_choice_table_names_each_candidates_input_side():
    from cmal_lcd.reports.tables import layer_choice_table

    row = {"val/recall_at_100p": 0.5, "val/auc_pr": 0.6, "val/single_frame_recall_at_1": 0.7}
    table = layer_choice_table({"selected": "block4", "image_size": 64, "candidates": [
        {"layer": "block4", "image_size": 224, **row}, {"layer": "block4", "image_size": 64, **row}]})
    assert table.index.tolist() == ["block4, 224 px", "block4, 64 px"]
    assert table["chosen"].tolist() == ["", "yes"]
