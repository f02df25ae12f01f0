"""Every figure the report writes is readable, judged on the drawn artists (issue 16, item 4):
finite data on every axes, a legend naming every method, no overlapping tick labels, no
overlapping bars. Inputs have the report's size (six methods, three pairs, two routes).
"""

import numpy as np
import pandas as pd
import pytest
from figure_checks import (assert_axis_labels_do_not_overlap, assert_bars_do_not_overlap,
                           assert_every_axes_has_finite_data, assert_text_inside_the_figure,
                           assert_legend_names, assert_readable, assert_tick_labels_do_not_overlap,
                           drawn)
from matplotlib import pyplot as plt

from cmal_lcd.reports import figures

METHODS = ["sad", "dnn", "dnn_head", "bigan", "cmal", "cmal_untrained"]
LABELS = {"sad": "SAD", "dnn": "DNN (VGG16)", "dnn_head": "DNN + head", "bigan": "BiGAN",
          "cmal": "CMAL", "cmal_untrained": "CMAL (untrained control)"}
PAIRS = ["foggy-rainy", "foggy-sunny", "rainy-sunny"]
ROUTES = ["route1", "route2"]


@pytest.fixture(autouse=True)
def close_figures():
    yield
    plt.close("all")


def pr_curve(seed: int, n: int = 40) -> pd.DataFrame:
    rng = np.random.default_rng(seed)
    return pd.DataFrame({"recall": np.sort(rng.uniform(0, 1, n)),
                         "precision": np.sort(rng.uniform(0.2, 1, n))[::-1]})


def nested_metrics(routes=ROUTES, pairs=PAIRS, methods=METHODS) -> dict:
    rng = np.random.default_rng(0)
    return {r: {p: {m: {"auc_roc": rng.uniform(0.5, 1), "auc_pr": rng.uniform(0, 1)}
                    for m in methods} for p in pairs} for r in routes}


def test_pr_figure_is_readable():
    curves = {p: {m: pr_curve(i * 10 + j) for j, m in enumerate(METHODS)}
              for i, p in enumerate(PAIRS)}
    fig = figures.pr_curves_figure(curves, route="route1", labels=LABELS)
    assert_readable(fig, legend=[LABELS[m] for m in METHODS])


def test_pr_figure_with_a_nan_curve_fails_the_finite_data_check():
    """The check itself: a panel whose every curve is NaN is an empty plot."""
    nan = pd.DataFrame({"recall": [np.nan, np.nan], "precision": [np.nan, np.nan]})
    fig = figures.pr_curves_figure({"a-b": {"sad": nan}}, route="r", labels=LABELS)
    with pytest.raises(AssertionError, match="no finite data"):
        assert_every_axes_has_finite_data(drawn(fig))


def test_pr_figure_legend_names_a_method_missing_from_the_first_pair():
    """A method evaluated on some pairs only still appears in the figure legend."""
    curves = {"a-b": {"sad": pr_curve(0)}, "a-c": {"sad": pr_curve(1), "cmal": pr_curve(2)}}
    fig = figures.pr_curves_figure(curves, route="r", labels=LABELS)
    assert_legend_names(drawn(fig), ["SAD", "CMAL"])


@pytest.mark.parametrize("routes, pairs", [(ROUTES, PAIRS), (["nordland"], ["summer-winter"]),
                                           (["route1", "route2", "route3"], PAIRS)])
def test_auc_bars_figure_is_readable(routes, pairs):
    fig = figures.auc_bars_figure(nested_metrics(routes, pairs), methods=METHODS, labels=LABELS)
    assert_readable(fig, legend=[LABELS[m] for m in METHODS])
    for ax in fig.axes:
        assert len(ax.containers) == len(METHODS)


def test_bar_check_fails_on_bars_wider_than_their_group():
    """The check itself, on the issue's unreadable Fig. 10: bars 4.5 units wide on groups
    1 unit apart."""
    fig, ax = plt.subplots()
    for i in range(2):
        ax.bar(np.arange(3) + i * 4.5, [0.5] * 3, width=4.5)
    ax.set_xticks(np.arange(3))
    with pytest.raises(AssertionError, match="overlap"):
        assert_bars_do_not_overlap(ax)


def test_tick_label_check_fails_on_crowded_labels():
    fig, ax = plt.subplots(figsize=(2, 2))
    ax.set_xticks(np.arange(10), [f"route{i}\nfoggy-sunny" for i in range(10)])
    with pytest.raises(AssertionError, match="overlap"):
        assert_tick_labels_do_not_overlap(fig)


def matrices(seed: int, shape=(50, 40)) -> dict:
    rng = np.random.default_rng(seed)
    D = rng.uniform(size=shape)
    return {"D": D, "D_hat": (D - D.mean(0)) / D.std(0), "match": np.arange(shape[1]),
            "truth": np.arange(shape[1])}


#: The report's own labels: the longest decide whether the stacked y labels collide.
REPORT_LABELS = {**LABELS, "dnn": "DNN (EfficientNet-Lite0, block 4, 4x4, 64 px)",
                 "dnn_head": "DNN (EfficientNet-Lite0, pooled head)"}


def test_matrices_figure_is_readable():
    fig = figures.matrices_figure({m: matrices(i) for i, m in enumerate(METHODS)},
                                  labels=REPORT_LABELS, title="route1 foggy-sunny")
    assert_readable(fig)
    assert len([ax for ax in fig.axes if ax.get_images()]) == 2 * len(METHODS)
    for ax, method in zip(fig.axes[::2], METHODS):
        assert " ".join(ax.get_ylabel().split()).startswith(REPORT_LABELS[method])


def test_text_check_fails_on_a_label_cut_off_at_the_edge():
    fig, ax = plt.subplots(figsize=(3, 2))
    fig.subplots_adjust(left=0.02)
    ax.set_ylabel("a\nthree-line\nlabel")
    with pytest.raises(AssertionError, match="runs outside the figure"):
        assert_text_inside_the_figure(fig)


def test_axis_label_check_fails_on_labels_running_into_each_other():
    fig, axes = plt.subplots(2, 1, figsize=(3, 2))
    for ax in axes:
        ax.set_ylabel("a y label far too long for its panel's height")
    with pytest.raises(AssertionError, match="axis labels .* overlap"):
        assert_axis_labels_do_not_overlap(fig)


def test_an_all_non_finite_matrix_fails_the_finite_data_check():
    """The check itself: a matrix with no finite cell is drawn all grey."""
    arrays = {"D": np.full((5, 5), np.nan), "D_hat": np.full((5, 5), np.inf)}
    fig = figures.matrices_figure({"sad": arrays}, labels=LABELS, title="t")
    with pytest.raises(AssertionError, match="all grey"):
        assert_every_axes_has_finite_data(drawn(fig))


def test_reconstructions_figure_is_readable():
    rng = np.random.default_rng(0)
    images = [rng.integers(0, 256, (6, 64, 64, 3), dtype=np.uint8) for _ in range(4)]
    fig = figures.reconstructions_figure(*images, condition_a=["foggy"] * 6,
                                         condition_b=["sunny"] * 6,
                                         offset_b=[f"{i}.5 m, {i}° away" for i in range(6)])
    assert_readable(fig)
    # issue 37: B is A's place, and says so on B's own panel, row by row
    for i, ax in enumerate(fig.axes[3::4]):
        assert [t.get_text() for t in ax.texts] == [f"A's place, {i}.5 m, {i}° away"]
        assert ax.get_title() == "B (sunny)"


def training_log(n: int = 25) -> pd.DataFrame:
    rng = np.random.default_rng(0)
    it = np.arange(n) * 25
    log = pd.DataFrame({"iteration": it})
    for key in ("D/loss", "D/real", "D/fake", "G/adv", "G/loss", "E/recon", "C/acc",
                "C/acc_heldout"):
        log[key] = rng.uniform(0, 2, n)
    log["val/R@100P"] = np.where(it % 50 == 0, rng.uniform(0, 1, n), np.nan)
    return log


def test_training_curves_figure_is_readable_and_every_panel_names_its_keys():
    log = training_log()
    fig = figures.training_curves_figure(log, title="cmal: training log")
    assert_readable(fig, legend=[c for c in log.columns if c != "iteration"])
