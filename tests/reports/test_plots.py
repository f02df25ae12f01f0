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
