"""Shared figures: PR curves and the difference/enhanced matrices (paper Fig. 6)."""

import cv2
import numpy as np
import pytest

from cmal_lcd.reports.plots import plot_difference_matrices, plot_pr_curves


def test_pr_curves_png_has_content(tmp_path):
    recall = np.linspace(0.1, 0.8, 20)
    path = plot_pr_curves({"SAD": (recall, 1 - recall / 4), "CMAL": (recall, np.ones(20))},
                          path=tmp_path / "pr.png", title="route1 foggy-rainy")
    image = cv2.imread(str(path))
    assert image is not None and image.shape[0] > 100 and image.std() > 0


def test_pdf_output_is_byte_stable(tmp_path):
    curves = {"SAD": (np.array([0.5, 1.0]), np.array([1.0, 0.5]))}
    a = plot_pr_curves(curves, path=tmp_path / "a.pdf").read_bytes()
    b = plot_pr_curves(curves, path=tmp_path / "b.pdf").read_bytes()
    assert a.startswith(b"%PDF") and a == b


def test_matrices_figure_accepts_inf_cells_and_overlays(tmp_path):
    rng = np.random.default_rng(0)
    D = rng.random((30, 20)).astype(np.float32)
    D_hat = D.copy()
    D_hat[5:9, 3] = np.inf  # excluded constant windows
    match = np.where(np.arange(20) < 10, -1, np.arange(20))
    path = plot_difference_matrices(D, D_hat, path=tmp_path / "m.png", match=match,
                                    truth=np.arange(20), title="Fig. 6")
    assert cv2.imread(str(path)) is not None


def test_large_matrices_are_subsampled_for_display(tmp_path, monkeypatch):
    from cmal_lcd.reports import plots

    monkeypatch.setattr(plots, "MAX_DISPLAY_SIDE", 10)
    D = np.random.default_rng(1).random((95, 47))
    assert plot_difference_matrices(D, D, path=tmp_path / "big.png").exists()


@pytest.mark.parametrize("call, name", [
    (lambda p: plot_pr_curves({}, path=p / "x.png"), "curves"),
    (lambda p: plot_pr_curves({"a": (np.ones(2), np.ones(3))}, path=p / "x.png"), "recall"),
    (lambda p: plot_pr_curves({"a": (np.ones(2), np.ones(2))}, path=p / "x.svg"), "path"),
    (lambda p: plot_difference_matrices(np.ones((3, 3)), np.ones((3, 2)), path=p / "x.png"), "D"),
])
def test_invalid_inputs_raise(tmp_path, call, name):
    with pytest.raises(ValueError, match=name):
        call(tmp_path)


# --------------------------------------------------------------------- DVC plots files


def exact_curves(seed, *, first_correct):
    """A random set of scored queries: their exact PR curve, ROC curve and counts."""
    from cmal_lcd.evaluation import precision_recall_curve, roc_curve

    rng = np.random.default_rng(seed)
    n = 60
    confidence = np.round(rng.uniform(0, 1, n), 2)  # ties included
    correct = rng.uniform(0, 1, n) < 0.6
    best = np.flatnonzero(confidence == confidence.min())
    correct[best] = first_correct
    n_positive = int(correct.sum()) + 5  # 5 queries whose match is wrong but place present
    precision, recall, _ = precision_recall_curve(confidence, correct, n_positive=n_positive)
    fpr, tpr, _ = roc_curve(confidence, correct)
    return recall, precision, (fpr, tpr), n_positive, n


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_roc_from_pr_is_the_exact_roc_when_the_most_confident_match_is_right(seed):
    from cmal_lcd.reports.plots import roc_from_pr

    recall, precision, (fpr, tpr), n_positive, n = exact_curves(seed, first_correct=True)
    got_fpr, got_tpr = roc_from_pr(recall, precision, n_positive=n_positive, n_scored=n)
    np.testing.assert_allclose(got_fpr, fpr, atol=1e-12)
    np.testing.assert_allclose(got_tpr, tpr, atol=1e-12)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_roc_from_pr_keeps_only_exact_points_when_the_most_confident_match_is_wrong(seed):
    from cmal_lcd.reports.plots import roc_from_pr

    recall, precision, (fpr, tpr), n_positive, n = exact_curves(seed, first_correct=False)
    got_fpr, got_tpr = roc_from_pr(recall, precision, n_positive=n_positive, n_scored=n)
    exact = set(zip(np.round(fpr, 12), np.round(tpr, 12)))
    assert set(zip(np.round(got_fpr, 12), np.round(got_tpr, 12))) <= exact
    # everything after the wrong prefix is there: the points with tpr > 0, and the end (1, 1)
    assert np.sum(got_tpr > 0) == np.sum(tpr > 0)
    assert (got_fpr[-1], got_tpr[-1]) == (1.0, 1.0)


def test_roc_from_pr_is_empty_when_undefined():
    from cmal_lcd.reports.plots import roc_from_pr

    # every scored query correct: no false positive can be counted
    fpr, tpr = roc_from_pr(np.array([0.5, 1.0]), np.array([1.0, 1.0]), n_positive=4, n_scored=4)
    assert fpr.size == tpr.size == 0


def test_overlay_files_hold_every_method_of_a_pair_in_one_file(tmp_path):
    import pandas as pd

    from cmal_lcd.reports.plots import write_overlay_plots

    curves, counts = {}, {}
    for method, seed in (("sad", 0), ("cmal", 1)):
        recall, precision, _, n_positive, n = exact_curves(seed, first_correct=True)
        for pair in ("foggy-rainy", "rainy-sunny"):
            curves.setdefault("route1", {}).setdefault(pair, {})[method] = pd.DataFrame(
                {"recall": recall, "precision": precision,
                 "threshold": np.arange(recall.size, dtype=float)})
            counts.setdefault("route1", {}).setdefault(pair, {})[method] = {
                "n_positive": n_positive, "n_scored": n}
    paths = write_overlay_plots(tmp_path, curves, counts=counts,
                                labels={"sad": "SAD", "cmal": "CMAL"})
    assert sorted(str(p.relative_to(tmp_path)) for p in paths) == [
        "pr/route1/foggy-rainy.csv", "pr/route1/rainy-sunny.csv",
        "roc/route1/foggy-rainy.csv", "roc/route1/rainy-sunny.csv"]
    pr = pd.read_csv(tmp_path / "pr" / "route1" / "foggy-rainy.csv")
    assert list(pr.columns) == ["method", "point", "recall", "precision", "threshold"]
    assert list(pr["method"].unique()) == ["SAD", "CMAL"]
    sad = pr[pr["method"] == "SAD"]
    np.testing.assert_array_equal(sad["recall"], curves["route1"]["foggy-rainy"]["sad"]["recall"])
    assert list(sad["point"]) == list(range(len(sad)))
    roc = pd.read_csv(tmp_path / "roc" / "route1" / "foggy-rainy.csv")
    assert list(roc.columns) == ["method", "point", "fpr", "tpr"]
    assert list(roc["method"].unique()) == ["SAD", "CMAL"]


def test_dvc_yaml_declares_overlaid_pr_and_roc_charts_and_the_summary_metrics(repo_root):
    """The plots declared in dvc.yaml read the columns the writer writes, with a template that
    colours by method; the DVC metric is the one headline file; the per-method summary files
    are plain outputs."""
    import json

    import yaml

    spec = yaml.safe_load((repo_root / "dvc.yaml").read_text())
    declared = {}
    for entry in spec["plots"]:
        if isinstance(entry, dict):
            declared.update(entry)
    assert declared["reports/plots/pr"] == {"template": "methods_overlay", "x": "recall",
                                            "y": "precision"}
    assert declared["reports/plots/roc"] == {"template": "methods_overlay", "x": "fpr",
                                             "y": "tpr"}
    template = json.loads((repo_root / ".dvc" / "plots" / "methods_overlay.json").read_text())
    assert template["encoding"]["color"]["field"] == "method"
    assert template["encoding"]["order"]["field"] == "point"
    report = spec["stages"]["report"]
    assert [next(iter(m)) for m in report["metrics"]] == ["reports/summary.json"]
    outs = [next(iter(o)) if isinstance(o, dict) else o for o in report["outs"]]
    assert "reports/plots" in outs and "reports/summary" in outs
