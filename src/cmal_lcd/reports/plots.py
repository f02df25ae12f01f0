"""Figures shared by the ``match`` command and the report stage: PR curves and Fig. 6.

Figures are files, never windows: each function draws on its own ``matplotlib.figure.Figure``
(no global ``pyplot`` state) and writes it atomically; the format follows the suffix (``.png``
or ``.pdf``). PDFs carry no creation date, so the same data give the same bytes.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from cmal_lcd.io import atomic_path

#: Matrices larger than this many rows or columns are subsampled (by striding) for display.
MAX_DISPLAY_SIDE = 1200


def plot_pr_curves(curves: Mapping[str, tuple[np.ndarray, np.ndarray]], *,
                   path: str | os.PathLike, title: str | None = None) -> Path:
    """Precision-recall curves, one line per method, as in the paper's Figs. 8-9.

    Parameters
    ----------
    curves : mapping of str to (recall, precision)
        Label -> ``(recall float (T,), precision float (T,))``, thresholds ascending (as returned
        by :func:`cmal_lcd.evaluation.precision_recall_curve`, recall first).
    path : path-like
        Output file, ``.png`` or ``.pdf``.
    title : str, optional
        Axes title.

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    if not curves:
        raise ValueError("curves is empty: nothing to plot")
    fig = Figure(figsize=(5.0, 4.2))
    ax = fig.add_subplot()
    for label, (recall, precision) in curves.items():
        recall = np.asarray(recall, dtype=float)
        precision = np.asarray(precision, dtype=float)
        if recall.shape != precision.shape or recall.ndim != 1:
            raise ValueError(f"curves[{label!r}]: recall and precision must be 1-D of the same "
                             f"length, got {recall.shape} and {precision.shape}")
        ax.step(np.concatenate([[0.0], recall]), np.concatenate([precision[:1], precision]),
                where="pre", label=label, linewidth=1.4)
    ax.set_xlabel("recall")
    ax.set_ylabel("precision")
    ax.set_xlim(0.0, 1.0)
    ax.set_ylim(0.0, 1.02)
    ax.grid(True, alpha=0.3)
    ax.legend(loc="lower left", fontsize="small")
    if title:
        ax.set_title(title)
    fig.tight_layout()
    return _save(fig, path)


def plot_difference_matrices(D: np.ndarray, D_hat: np.ndarray, *, path: str | os.PathLike,
                             title: str | None = None,
                             match: np.ndarray | None = None,
                             truth: np.ndarray | None = None,
                             labels: Sequence[str] = ("difference matrix D (eq. 13)",
                                                      "enhanced matrix D_hat (eq. 14)")) -> Path:
    """The difference and the enhanced matrices side by side (paper Fig. 6).

    Parameters
    ----------
    D, D_hat : numpy.ndarray
        ``(R, Q)``: rows = reference frames (vertical axis), columns = query frames. ``+inf``
        cells of ``D_hat`` (excluded constant windows) are drawn in grey.
    path : path-like
        Output file, ``.png`` or ``.pdf``.
    title : str, optional
        Figure title.
    match, truth : numpy.ndarray, optional
        ``int (Q,)`` sequence matches and true places (``-1`` = none), overlaid as dots on the
        enhanced matrix.
    labels : pair of str
        Panel titles.

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    D = np.asarray(D)
    D_hat = np.asarray(D_hat)
    if D.ndim != 2 or D_hat.shape != D.shape:
        raise ValueError(f"D and D_hat must be 2-D of the same shape, got {D.shape} and "
                         f"{D_hat.shape}")
    R, Q = D.shape
    step_r = max(1, -(-R // MAX_DISPLAY_SIDE))
    step_q = max(1, -(-Q // MAX_DISPLAY_SIDE))
    fig = Figure(figsize=(10.0, 4.6))
    axes = fig.subplots(1, 2)
    for ax, matrix, label in zip(axes, (D, D_hat), labels):
        shown = np.ma.masked_invalid(np.asarray(matrix[::step_r, ::step_q], dtype=np.float64))
        cmap = _grey_bad_cmap()
        image = ax.imshow(shown, aspect="auto", interpolation="nearest", cmap=cmap,
                          origin="upper", extent=(-0.5, Q - 0.5, R - 0.5, -0.5))
        fig.colorbar(image, ax=ax, fraction=0.046, pad=0.03)
        ax.set_xlabel("query frame")
        ax.set_ylabel("reference frame")
        ax.set_title(label, fontsize="medium")
    for values, colour, name in ((truth, "lime", "true place"), (match, "red", "match")):
        if values is None:
            continue
        values = np.asarray(values)
        if values.shape != (Q,):
            raise ValueError(f"{name} must have shape ({Q},), got {values.shape}")
        q = np.flatnonzero(values >= 0)
        axes[1].scatter(q, values[q], s=1.5, c=colour, label=name, linewidths=0)
    if match is not None or truth is not None:
        axes[1].legend(loc="upper right", fontsize="x-small", markerscale=4)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return _save(fig, path)


def _grey_bad_cmap():
    import matplotlib

    return matplotlib.colormaps["viridis"].with_extremes(bad="0.6")


def _save(fig: Figure, path: str | os.PathLike) -> Path:
    """Write ``fig`` to ``path`` atomically, in the format of its suffix."""
    path = Path(path)
    fmt = path.suffix.lower().lstrip(".")
    if fmt not in ("png", "pdf"):
        raise ValueError(f"path must end in .png or .pdf, got {path}")
    FigureCanvasAgg(fig)
    metadata = {"CreationDate": None} if fmt == "pdf" else {"Software": None}
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format=fmt, dpi=150, metadata=metadata)
    return path
