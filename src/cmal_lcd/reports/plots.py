"""Figures shared by the ``match`` command and the report stage (PR curves, Fig. 6), and the
data files of ``dvc plots`` (every method overlaid on one PR and one ROC chart per pair).

Figures are files, never windows: each function draws on its own ``matplotlib.figure.Figure``
(no global ``pyplot`` state) and writes it atomically; the format follows the suffix (``.png``
or ``.pdf``). PDFs carry no creation date, so the same data give the same bytes.

DVC plots files (:func:`write_overlay_plots`): ``<out>/pr/<route>/<pair>.csv`` with columns
``method, point, recall, precision, threshold`` and ``<out>/roc/<route>/<pair>.csv`` with
``method, point, fpr, tpr``: one file per route and pair, one block of rows per method (its table
label), ``point`` the order along the curve. ``dvc.yaml`` declares both folders with the
``methods_overlay`` template (``.dvc/plots/``), which colours the lines by ``method``, so each
chart overlays every method as the paper's Figs. 8-9 do.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from cmal_lcd.io import atomic_path, atomic_write_text

if TYPE_CHECKING:  # pandas only for the DVC plot files: `cmal-lcd match` figures need none
    import pandas as pd

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
                                                      "enhanced matrix D_hat (eq. 14)"),
                             frames: tuple[int, int] | None = None) -> Path:
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
    frames : (int, int), optional
        ``(R_frames, Q_frames)`` when ``D`` and ``D_hat`` hold every k-th reference and query
        frame of longer drives (``R = ceil(R_frames / k)``): the axes and ``match``/``truth``
        (then ``(Q_frames,)``) stay in frames. Default: ``D.shape``.

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
    R, Q = D.shape if frames is None else (int(frames[0]), int(frames[1]))
    fig = Figure(figsize=(10.0, 4.6))
    axes = _draw_matrix_panels(fig, (D, D_hat), labels, extent_shape=(R, Q))
    _overlay_places(axes[1], match=match, truth=truth, n_query=Q)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return _save(fig, path)


def _draw_matrix_panels(fig: Figure, matrices: Sequence[np.ndarray], labels: Sequence[str], *,
                        extent_shape: tuple[int, int]) -> np.ndarray:
    """One panel per ``(R', Q')`` matrix, strided to at most :data:`MAX_DISPLAY_SIDE` a side
    and drawn over ``extent_shape`` ``(R, Q)`` frames; returns the axes."""
    R, Q = extent_shape
    step_r = max(1, -(-matrices[0].shape[0] // MAX_DISPLAY_SIDE))
    step_q = max(1, -(-matrices[0].shape[1] // MAX_DISPLAY_SIDE))
    axes = fig.subplots(1, len(matrices))
    for ax, matrix, label in zip(axes, matrices, labels):
        shown = np.ma.masked_invalid(np.asarray(matrix[::step_r, ::step_q], dtype=np.float64))
        cmap = _grey_bad_cmap()
        image = ax.imshow(shown, aspect="auto", interpolation="nearest", cmap=cmap,
                          origin="upper", extent=(-0.5, Q - 0.5, R - 0.5, -0.5))
        fig.colorbar(image, ax=ax, fraction=0.046, pad=0.03)
        ax.set_xlabel("query frame")
        ax.set_ylabel("reference frame")
        ax.set_title(label, fontsize="medium")
    return axes


def _overlay_places(ax, *, match: np.ndarray | None, truth: np.ndarray | None,
                    n_query: int) -> None:
    """True places and matches, ``int (n_query,)`` (``-1`` = none), as dots on ``ax``."""
    for values, colour, name in ((truth, "lime", "true place"), (match, "red", "match")):
        if values is None:
            continue
        values = np.asarray(values)
        if values.shape != (n_query,):
            raise ValueError(f"{name} must have shape ({n_query},), got {values.shape}")
        q = np.flatnonzero(values >= 0)
        ax.scatter(q, values[q], s=1.5, c=colour, label=name, linewidths=0)
    if match is not None or truth is not None:
        ax.legend(loc="upper right", fontsize="x-small", markerscale=4)


def roc_from_pr(recall: np.ndarray, precision: np.ndarray, *, n_positive: int,
                n_scored: int) -> tuple[np.ndarray, np.ndarray]:
    """The ROC curve (:func:`cmal_lcd.evaluation.roc_curve`) recovered from the exact PR curve.

    At each threshold ``TP = recall * n_positive`` and, where ``TP > 0``, ``accepted = TP /
    precision``; with ``n_correct = TP`` at the last threshold (everything accepted) and
    ``n_incorrect = n_scored - n_correct``: ``tpr = TP / n_correct``, ``fpr = (accepted - TP) /
    n_incorrect``. Thresholds with ``TP = 0`` (the most confident matches all wrong) do not
    tell how many queries they accept, so they are left out: the curve then runs straight
    from ``(0, 0)`` to its first point with ``TP > 0`` (the exact curve runs along ``tpr = 0``
    first); every point drawn is a point of the exact curve.

    Parameters
    ----------
    recall, precision : numpy.ndarray
        ``float (T,)`` the exact PR curve, thresholds ascending.
    n_positive, n_scored : int
        The recall denominator and the number of scored queries (``metrics.json``).

    Returns
    -------
    fpr, tpr : numpy.ndarray
        ``float64 (P + 1,)``, starting at ``(0, 0)``; empty when the ROC is undefined (no
        correct or no wrong match, or an empty curve).
    """
    recall = np.asarray(recall, dtype=np.float64)
    precision = np.asarray(precision, dtype=np.float64)
    if recall.shape != precision.shape or recall.ndim != 1:
        raise ValueError(f"recall and precision must be 1-D of the same length, got "
                         f"{recall.shape} and {precision.shape}")
    empty = np.zeros(0), np.zeros(0)
    if recall.size == 0:
        return empty
    tp = np.rint(recall * n_positive)
    known = (tp > 0) & (precision > 0)
    accepted = np.rint(np.divide(tp, precision, out=np.zeros_like(tp), where=known))
    n_correct = float(tp[-1])
    n_incorrect = float(n_scored) - n_correct
    if n_correct <= 0 or n_incorrect <= 0:
        return empty
    fpr = np.concatenate([[0.0], (accepted[known] - tp[known]) / n_incorrect])
    tpr = np.concatenate([[0.0], tp[known] / n_correct])
    return np.clip(fpr, 0.0, 1.0), np.clip(tpr, 0.0, 1.0)


def write_overlay_plots(out_dir: str | os.PathLike,
                        curves: Mapping[str, Mapping[str, Mapping[str, pd.DataFrame]]], *,
                        counts: Mapping[str, Mapping[str, Mapping[str, Mapping[str, int]]]],
                        labels: Mapping[str, str]) -> list[Path]:
    """Write the ``dvc plots`` files: one PR and one ROC file per route and pair, all methods.

    Parameters
    ----------
    out_dir : path-like
        Folder to write ``pr/<route>/<pair>.csv`` and ``roc/<route>/<pair>.csv`` into (the
        report's ``plots/``).
    curves : mapping
        ``{route: {pair: {method: DataFrame}}}``, each with columns ``recall, precision`` and
        optionally ``threshold`` (the evaluate stage's ``pr/<route>/<pair>.csv``), in method
        order.
    counts : mapping
        ``{route: {pair: {method: {"n_positive": int, "n_scored": int}}}}`` for the ROC
        (:func:`roc_from_pr`); a method without counts or with an undefined ROC has no ROC rows.
    labels : mapping
        Method -> the name written in the ``method`` column.

    Returns
    -------
    list of Path
        The files written, PR then ROC per pair.
    """
    import pandas as pd

    out_dir = Path(out_dir)
    written = []
    for route, per_pair in curves.items():
        for pair, per_method in per_pair.items():
            pr_parts, roc_parts = _overlay_parts(per_method, counts.get(route, {}).get(pair, {}),
                                                 labels)
            for kind, parts in (("pr", pr_parts), ("roc", roc_parts)):
                if not parts:
                    continue
                table = pd.concat(parts, ignore_index=True)
                written.append(atomic_write_text(out_dir / kind / route / f"{pair}.csv",
                                                 table.to_csv(index=False,
                                                              lineterminator="\n")))
    return written


def _overlay_parts(per_method: Mapping[str, pd.DataFrame],
                   counts: Mapping[str, Mapping[str, int]], labels: Mapping[str, str]
                   ) -> tuple[list[pd.DataFrame], list[pd.DataFrame]]:
    """The PR and ROC rows of every method of one pair (``counts``: that pair's, per method)."""
    import pandas as pd

    pr_parts, roc_parts = [], []
    for method, curve in per_method.items():
        label = labels.get(method, method)
        part = pd.DataFrame({"method": label, "point": np.arange(len(curve)),
                             "recall": curve["recall"].to_numpy(float),
                             "precision": curve["precision"].to_numpy(float)})
        if "threshold" in curve:
            part["threshold"] = curve["threshold"].to_numpy(float)
        pr_parts.append(part)
        count = counts.get(method)
        if count is None:
            continue
        fpr, tpr = roc_from_pr(part["recall"].to_numpy(), part["precision"].to_numpy(),
                               n_positive=int(count["n_positive"]),
                               n_scored=int(count["n_scored"]))
        if fpr.size:
            roc_parts.append(pd.DataFrame({"method": label, "point": np.arange(fpr.size),
                                           "fpr": fpr, "tpr": tpr}))
    return pr_parts, roc_parts


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
