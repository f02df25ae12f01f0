"""Figures: arrays in, matplotlib figures out; saved as byte-stable PNG and PDF."""

import numpy as np
import pandas as pd
import pytest
from matplotlib.image import AxesImage

from cmal_lcd.reports import figures

LABELS = {"sad": "SAD", "cmal": "CMAL", "cmal_untrained": "CMAL (untrained control)"}


def curve(n: int, seed: int) -> pd.DataFrame:
    rng = np.random.default_rng(seed)
    return pd.DataFrame({"recall": np.sort(rng.uniform(0, 1, n)),
                         "precision": np.sort(rng.uniform(0, 1, n))[::-1]})


def test_method_styles_are_fixed_and_controls_dashed():
    styles = figures.method_styles(["sad", "cmal", "cmal_untrained", "new_a", "new_b"])
    assert styles["cmal"]["color"] == figures.METHOD_COLOURS["cmal"]
    assert styles["cmal_untrained"]["linestyle"] == "--"
    assert styles["cmal"]["linestyle"] == "-"
    assert styles["new_a"]["color"] != styles["new_b"]["color"]
    # a method keeps its colour whatever the other methods are
    assert figures.method_styles(["cmal"])["cmal"] == styles["cmal"]


def test_pr_figure_has_a_panel_per_pair_and_a_curve_per_method_labelled():
    curves = {"foggy-rainy": {"sad": curve(5, 0), "cmal": curve(7, 1)},
              "foggy-sunny": {"sad": curve(4, 2), "cmal": curve(6, 3)},
              "rainy-sunny": {"sad": curve(3, 4), "cmal": curve(3, 5)}}
    fig = figures.pr_curves_figure(curves, route="route1", labels=LABELS)
    axes = [ax for ax in fig.axes if ax.lines]
    assert [ax.get_title() for ax in axes] == [f"{p} (reference-query)" for p in curves]
    assert all(len(ax.lines) == 2 for ax in axes)
    assert [line.get_label() for line in axes[0].lines] == ["SAD", "CMAL"]
    # a step curve starting at recall 0 with the first precision
    drawn = axes[1].lines[1]
    source = curves["foggy-sunny"]["cmal"]
    np.testing.assert_array_equal(drawn.get_xdata(), [0.0, *source["recall"]])
    np.testing.assert_array_equal(drawn.get_ydata(), [source["precision"][0], *source["precision"]])
    assert drawn.get_drawstyle() == "steps-pre"


def test_coinciding_pr_curves_stay_visible_as_nested_stripes():
    same = curve(5, 0)
    fig = figures.pr_curves_figure({"a-b": {"sad": same, "cmal": same.copy()}}, route="r",
                                   labels=LABELS)
    under, over = [ax for ax in fig.axes if ax.lines][0].lines
    assert under.get_linewidth() > over.get_linewidth() and under.get_zorder() < over.get_zorder()


def test_pr_figure_needs_a_pair():
    with pytest.raises(ValueError, match="curves"):
        figures.pr_curves_figure({}, route="r", labels=LABELS)


def test_auc_bars_have_the_metric_values_as_heights():
    nested = {"route1": {"a-b": {"sad": {"auc_roc": 0.9, "auc_pr": 0.4},
                                 "cmal": {"auc_roc": 0.5, "auc_pr": float("nan")}}},
              "route2": {"a-b": {"sad": {"auc_roc": 0.7, "auc_pr": 0.3},
                                 "cmal": {"auc_roc": 0.6, "auc_pr": 0.2}}}}
    fig = figures.auc_bars_figure(nested, methods=["sad", "cmal"], labels=LABELS)
    roc, pr = fig.axes[:2]
    heights = [bar.get_height() for bar in roc.patches]
    assert heights == pytest.approx([0.9, 0.7, 0.5, 0.6])  # method by method, pairs in order
    assert [bar.get_height() for bar in pr.patches] == pytest.approx([0.4, 0.3, 0.0, 0.2])
    assert roc.get_ylabel() == "AUC-ROC"
    # an undefined value is said, not shown as an empty slot: one mark, at the missing bar
    marks = [t for t in pr.texts if t.get_text() == "undefined"]
    assert len(marks) == 1 and not [t for t in roc.texts if t.get_text() == "undefined"]
    assert marks[0].get_position()[0] == pytest.approx(pr.patches[2].get_x()
                                                       + pr.patches[2].get_width() / 2)


def test_auc_bars_of_one_pair_do_not_overlap_and_sit_around_their_tick():
    methods = ["sad", "dnn", "bigan", "cmal", "cmal_untrained"]
    nested = {route: {pair: {m: {"auc_roc": 0.5, "auc_pr": 0.5} for m in methods}
                      for pair in ("a-b", "a-c", "b-c")} for route in ("route1", "route2")}
    fig = figures.auc_bars_figure(nested, methods=methods, labels=LABELS)
    roc = fig.axes[0]
    bars = sorted(roc.patches, key=lambda b: b.get_x())
    for left, right in zip(bars, bars[1:]):
        assert left.get_x() + left.get_width() <= right.get_x() + 1e-9
    ticks = roc.get_xticks()
    for k, tick in enumerate(ticks):
        group = bars[k * len(methods):(k + 1) * len(methods)]
        assert (group[0].get_x() >= tick - 0.5
                and group[-1].get_x() + group[-1].get_width() <= tick + 0.5)


def test_matrices_figure_shows_d_and_d_hat_for_every_method():
    rng = np.random.default_rng(0)
    arrays = {"D": rng.uniform(size=(6, 5)), "D_hat": rng.normal(size=(6, 5)),
              "match": np.array([-1, 1, 2, 3, 4]), "truth": np.array([0, 1, 2, 3, -1])}
    fig = figures.matrices_figure({"sad": arrays, "cmal": arrays}, labels=LABELS, title="t")
    images = [im for ax in fig.axes for im in ax.get_images()]
    assert len(images) == 4
    assert isinstance(images[0], AxesImage)
    np.testing.assert_array_equal(images[1].get_array(), arrays["D_hat"])
    assert fig.axes[0].get_ylabel().startswith("SAD")
    # overlay: the true place of the 4 queries that have one, matches of the 4 scored ones
    d_hat_ax = fig.axes[1]
    np.testing.assert_array_equal(d_hat_ax.lines[0].get_xdata(), [0, 1, 2, 3])
    assert len(d_hat_ax.collections[0].get_offsets()) == 4
    assert d_hat_ax.collections[0].get_zorder() > d_hat_ax.lines[0].get_zorder()  # dots on top


def test_matrices_figure_says_when_the_search_used_d_itself_and_bands_the_tolerance():
    rng = np.random.default_rng(0)
    D = rng.uniform(size=(30, 20))
    truth = np.arange(20) + 5
    truth[3] = -1
    plain = {"D": D, "D_hat": D.copy(), "match": truth.copy(), "truth": truth}
    enhanced = {**plain, "D_hat": D - D.mean(axis=0)}
    fig = figures.matrices_figure({"sad": plain, "cmal": enhanced}, labels=LABELS, title="t",
                                  d_thresh=2)
    panels = fig.axes[:4]
    assert "itself (not enhanced)" in panels[1].get_title()
    assert "eq. 14" in panels[3].get_title() and "itself" not in panels[3].get_title()
    assert len(fig.axes) == 8  # a colour bar beside each of the four panels
    # the band spans truth +- d_thresh (+ half a cell), broken where a query has no true place
    band = panels[1].collections[0].get_paths()
    ys = np.concatenate([p.vertices[:, 1] for p in band])
    assert ys.min() == pytest.approx(5 - 2.5) and ys.max() == pytest.approx(24 + 2.5)
    assert len(band) == 2
    assert panels[1].get_ylim() == (29.5, -0.5)  # the band never stretches the axes


def test_matrices_figure_greys_non_finite_cells_and_strides_large_matrices(monkeypatch):
    monkeypatch.setattr(figures, "MAX_DISPLAY_SIDE", 4)
    D = np.arange(80, dtype=float).reshape(10, 8)
    D_hat = D.copy()
    D_hat[0, 0] = np.inf
    fig = figures.matrices_figure({"sad": {"D": D, "D_hat": D_hat}}, labels=LABELS, title="t")
    shown = fig.axes[1].get_images()[0]
    assert shown.get_array().shape == (4, 4)  # every 3rd row, every 2nd column
    assert shown.get_array().mask[0, 0]
    assert shown.get_extent() == [-0.5, 7.5, 9.5, -0.5]  # axes still count frames


def test_matrices_figure_rejects_a_non_matrix():
    with pytest.raises(ValueError, match="D_hat"):
        figures.matrices_figure({"sad": {"D": np.zeros((2, 2)), "D_hat": np.zeros(3)}},
                                labels=LABELS, title="t")


def test_reconstructions_figure_has_four_columns_per_sample():
    images = [np.full((5, 4, 6, 3), i * 40, np.uint8) for i in range(4)]
    fig = figures.reconstructions_figure(*images, condition_a=["fog"] * 5,
                                         condition_b=["rain"] * 5, max_rows=3)
    assert len(fig.axes) == 12
    assert [ax.get_title() for ax in fig.axes[:4]] == [
        "A (fog)", "De(En(A)|fog)", "De(En(A)|rain)", "B (rain)"]


def test_reconstructions_figure_rejects_mismatched_arrays():
    good = np.zeros((2, 4, 6, 3), np.uint8)
    with pytest.raises(ValueError, match="translated_b"):
        figures.reconstructions_figure(good, good, np.zeros((3, 4, 6, 3), np.uint8), good,
                                       condition_a=["a", "a"], condition_b=["b", "b"])


def test_training_curves_one_panel_per_module():
    log = pd.DataFrame({"iteration": [0, 1, 2], "D/loss": [1, 2, 3], "G/adv": [3, 2, 1],
                        "G/recon": [1, 1, 1], "C/acc_heldout": [0.3, 0.5, 0.7]})
    fig = figures.training_curves_figure(log, title="cmal")
    panels = [ax for ax in fig.axes if ax.lines]
    assert [ax.get_title() for ax in panels] == ["D", "G", "C"]
    assert len(panels[1].lines) == 2
    with pytest.raises(ValueError, match="iteration"):
        figures.training_curves_figure(log.drop(columns="iteration"), title="x")


def test_training_curves_split_a_module_whose_keys_differ_in_scale():
    """Code norms (~13) and reconstruction losses (~0.05) on one axis would flatten the
    losses: they get a panel each, titled by scale; keys of one scale stay together."""
    it = np.arange(4)
    log = pd.DataFrame({"iteration": it, "E/recon": [0.09, 0.06, 0.05, 0.04],
                        "E/code_norm": [11.0, 12.5, 13.0, 13.4], "E/prior": [2.0, 3.0, 3.1, 2.7],
                        "E/adversary": [0.2, 0.3, 0.25, np.nan], "E/latent": [0.0] * 4,
                        "D/loss": [1.0, 1.5, 1.2, 1.6], "D/real": [0.7, 0.4, 0.5, 0.45]})
    panels = figures.training_panels(log, [c for c in log.columns if c != "iteration"])
    assert panels == [("E (|value| <= 13)", ["E/code_norm", "E/prior"]),
                      ("E (|value| <= 0.3)", ["E/recon", "E/adversary", "E/latent"]),
                      ("D", ["D/loss", "D/real"])]
    fig = figures.training_curves_figure(log, title="cmal")
    drawn = [ax for ax in fig.axes if ax.lines]
    assert [ax.get_title() for ax in drawn] == [title for title, _ in panels]
    assert [len(ax.lines) for ax in drawn] == [2, 3, 2]


def test_training_curves_label_every_y_axis_count_whole_iterations_and_mark_the_kept_one():
    """Issue 37: unlabelled y axes, ticks at 1.5 iterations on short runs, and no mark of the
    iteration model.pt keeps."""
    log = pd.DataFrame({"iteration": [0, 1, 2, 3, 4], "D/loss": [1.0, 1.2, 1.1, 1.3, 1.2],
                        "D/real": [0.6, 0.5, 0.55, 0.5, 0.52],
                        "C/acc_heldout": [0.3, 0.5, 0.7, 0.8, 0.8],
                        "E/code_norm_heldout": [11.0, 12.0, 12.5, 13.0, 13.1],
                        "val/recall_at_100p": [0.2, np.nan, 0.4, np.nan, 0.35]})
    fig = figures.training_curves_figure(log, title="cmal", kept_iteration=2)
    fig.canvas.draw()
    drawn = {ax.get_title(): ax for ax in fig.axes if ax.lines}
    assert drawn["D"].get_ylabel() == "loss; accuracy or D(x) (0-1)"
    assert drawn["C"].get_ylabel() == "accuracy or D(x) (0-1)"
    assert drawn["E"].get_ylabel() == "code L2 norm"
    assert drawn["val"].get_ylabel() == "validation score (0-1)"
    for title, ax in drawn.items():
        ticks = [t for t in ax.get_xticks() if ax.get_xlim()[0] <= t <= ax.get_xlim()[1]]
        assert ticks and all(float(t).is_integer() for t in ticks), (title, ticks)
        kept = [line for line in ax.lines if line.get_label() == "kept: iteration 2"]
        assert len(kept) == 1 and list(kept[0].get_xdata()) == [2, 2], title
    unmarked = figures.training_curves_figure(log, title="cmal")
    assert not any("kept" in line.get_label() for ax in unmarked.axes for line in ax.lines)


def test_saved_png_and_pdf_are_byte_identical_across_saves(tmp_path):
    curves = {"a-b": {"sad": curve(5, 0), "cmal_untrained": curve(5, 1)}}
    first = figures.save_figure(figures.pr_curves_figure(curves, route="r", labels=LABELS),
                                tmp_path / "one" / "fig")
    second = figures.save_figure(figures.pr_curves_figure(curves, route="r", labels=LABELS),
                                 tmp_path / "two" / "fig")
    assert [p.name for p in first] == ["fig.png", "fig.pdf"]
    assert first[0].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert first[1].read_bytes()[:5] == b"%PDF-"
    assert b"CreationDate" not in first[1].read_bytes()
    for a, b in zip(first, second):
        assert a.read_bytes() == b.read_bytes()
