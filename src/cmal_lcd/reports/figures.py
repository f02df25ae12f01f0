"""The report's figures (paper Figs. 6, 8-11), drawn with matplotlib's Agg backend.

Each ``*_figure`` function takes arrays or tables and returns a ``Figure`` (no I/O);
:func:`save_figure` writes it as PNG and PDF with byte-stable output (fixed style and dpi, no
creation date in the PDF). Methods keep one colour and line style across every figure
(:func:`method_styles`), and are always shown by their table label.
"""

from __future__ import annotations

import logging
import math
import textwrap
from pathlib import Path
from typing import Mapping, Sequence

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402

from cmal_lcd.io import atomic_path  # noqa: E402
from cmal_lcd.reports.plots import MAX_DISPLAY_SIDE  # noqa: E402
from cmal_lcd.reports.tables import METRIC_LABELS, metric_value, route_pairs  # noqa: E402

logger = logging.getLogger(__name__)

#: Fixed style: the same bytes on every run with the same matplotlib.
STYLE = {
    "font.family": "DejaVu Sans",
    "font.size": 8,
    "axes.titlesize": 9,
    "axes.labelsize": 8,
    "legend.fontsize": 7,
    "figure.dpi": 100,
    "savefig.dpi": 150,
    "svg.hashsalt": "cmal-lcd",
    "path.simplify": False,
}
#: Colours by method name (others cycle through the tab10 palette).
METHOD_COLOURS = {"sad": "tab:gray", "dnn": "tab:blue", "dnn_head": "tab:cyan",
                  "bigan": "tab:orange", "cmal": "tab:red", "cmal_untrained": "tab:pink",
                  "cmal_place": "tab:green", "place_encoder": "tab:olive"}


def method_styles(methods: Sequence[str]) -> dict[str, dict]:
    """Line style per method: a fixed colour, dashed for controls (names ending ``_untrained``).

    Returns
    -------
    dict
        ``{method: {"color", "linestyle"}}`` for ``plt.plot``.
    """
    palette = plt.get_cmap("tab10").colors
    styles = {}
    for i, method in enumerate(methods):
        colour = METHOD_COLOURS.get(method, palette[i % len(palette)])
        styles[method] = {"color": colour,
                          "linestyle": "--" if method.endswith("_untrained") else "-"}
    return styles


def new_figure(*, width: float, height: float, layout: str | None = "constrained") -> Figure:
    """An empty figure of ``width`` x ``height`` inches in the fixed style.

    ``layout=None`` (fixed margins) draws much faster than ``"constrained"`` for grids of
    images.
    """
    with plt.rc_context(STYLE):
        return Figure(figsize=(width, height), dpi=STYLE["figure.dpi"], layout=layout)


def save_figure(fig: Figure, stem: str | Path, *, png_dpi: float | None = None) -> list[Path]:
    """Write ``<stem>.png`` and ``<stem>.pdf`` atomically; same figure -> same bytes.

    ``png_dpi`` overrides the style's resolution for the PNG (dense matrix images compress
    badly; the PDF keeps every cell).

    Returns
    -------
    list of Path
        The two files.
    """
    stem = Path(stem)
    paths = []
    with plt.rc_context(STYLE):
        for suffix, metadata in ((".png", {"Software": None}), (".pdf", {"CreationDate": None})):
            path = stem.with_suffix(suffix)
            with atomic_path(path) as tmp:
                dpi = png_dpi if (png_dpi and suffix == ".png") else STYLE["savefig.dpi"]
                fig.savefig(tmp, format=suffix[1:], metadata=metadata, dpi=dpi)
            paths.append(path)
    logger.info("wrote figure %s.{png,pdf}", stem)
    return paths


def _legend_columns(names: Sequence[str], *, width: float) -> int:
    """Legend columns that fit ``names`` (at the style's 7 pt legend font) in ``width``
    inches."""
    column = 0.5 + 0.06 * max((len(name) for name in names), default=0)
    return max(1, min(len(names), int(width // column)))


def _grid(n: int, *, max_columns: int = 3) -> tuple[int, int]:
    columns = min(n, max_columns)
    return math.ceil(n / columns), columns


def stacked_widths(n: int, *, thinnest: float = 1.0, step: float = 0.45) -> list[float]:
    """Line widths (points) of ``n`` curves drawn in order, the last ``thinnest``: each one
    ``step`` wider than the next, so that where curves coincide every one stays visible."""
    return [thinnest + step * (n - 1 - i) for i in range(n)]


def pr_curves_figure(curves: Mapping[str, Mapping[str, pd.DataFrame]], *, route: str,
                     labels: Mapping[str, str],
                     styles: Mapping[str, dict] | None = None) -> Figure:
    """Figs. 8-9: precision-recall curves of every method, one panel per pair of a route.

    Parameters
    ----------
    curves : mapping
        ``{pair: {method: DataFrame with columns recall, precision}}``, thresholds ascending
        (the evaluate stage's PR files). Drawn as steps starting at recall 0.
    route : str
        Shown in the title.
    labels : mapping
        Legend label per method.
    """
    if not curves:
        raise ValueError("curves: no pairs to plot")
    methods = list(dict.fromkeys(m for per_method in curves.values() for m in per_method))
    styles = styles or method_styles(methods)
    rows, columns = _grid(len(curves))
    with plt.rc_context(STYLE):
        width = max(4.5, 3.0 * columns)
        names = [labels.get(m, m) for m in methods]
        legend_rows = math.ceil(len(names) / _legend_columns(names, width=width))
        # the legend below takes its own height, never the panels'
        fig = new_figure(width=width, height=2.8 * rows + 0.4 + 0.16 * legend_rows)
        axes = np.atleast_1d(fig.subplots(rows, columns, squeeze=False)).ravel()
        widths = stacked_widths(len(methods))
        for ax, (pair, per_method) in zip(axes, curves.items()):
            for method, curve in per_method.items():
                recall = curve["recall"].to_numpy(float)
                precision = curve["precision"].to_numpy(float)
                rank = methods.index(method)
                # precision is constant between two recall levels: a step from recall 0, as
                # cmal_lcd.reports.plots.plot_pr_curves draws it for the `match` command;
                # each later method thinner and on top, so curves that coincide (all at
                # precision 1) show as nested stripes instead of hiding each other
                ax.step(np.concatenate([[0.0], recall]),
                        np.concatenate([precision[:1], precision]), where="pre",
                        label=labels.get(method, method), linewidth=widths[rank],
                        zorder=2 + rank, **styles[method])
            ax.set(title=f"{pair} (reference-query)", xlabel="recall", ylabel="precision",
                   xlim=(0, 1), ylim=(0, 1.04))
            ax.grid(True, linewidth=0.4, alpha=0.5)
        for ax in axes[len(curves):]:
            ax.set_axis_off()
        # every method once, also one missing from the first pair's panel
        by_name = {}
        for ax in axes[:len(curves)]:
            for handle, name in zip(*ax.get_legend_handles_labels()):
                by_name.setdefault(name, handle)
        names = list(by_name)
        fig.legend(list(by_name.values()), names, loc="outside lower center",
                   ncol=_legend_columns(names, width=width), frameon=False)
        fig.suptitle(f"Precision-recall, {route}")
    return fig


def auc_bars_figure(nested: Mapping, *, methods: Sequence[str], labels: Mapping[str, str],
                    metrics: Sequence[str] = ("auc_roc", "auc_pr"),
                    styles: Mapping[str, dict] | None = None) -> Figure:
    """Fig. 10: grouped bars of the area under the curve, one group per route and pair.

    Parameters
    ----------
    nested : mapping
        ``{route: {pair: {method: {metric: value}}}}``.
    metrics : sequence of str
        One panel per metric (default AUC-ROC and AUC-PR).
    """
    groups = route_pairs(nested)
    if not groups:
        raise ValueError("nested: no route/pair to plot")
    styles = styles or method_styles(methods)
    bar_width = 0.8 / max(len(methods), 1)
    x = np.arange(len(groups), dtype=float)
    with plt.rc_context(STYLE):
        fig_width = max(4.5, 1.1 * len(groups) + 1.5)
        fig = new_figure(width=fig_width, height=2.4 * len(metrics) + 0.7)
        axes = np.atleast_1d(fig.subplots(len(metrics), 1, squeeze=False)).ravel()
        for ax, metric in zip(axes, metrics):
            for i, method in enumerate(methods):
                values = [metric_value(nested, r, p, method, metric) for r, p in groups]
                positions = x + (i - (len(methods) - 1) / 2) * bar_width
                for position, value in zip(positions, values):
                    if not np.isfinite(value):  # e.g. AUC-ROC when every query is correct
                        ax.text(position, 0.02, "undefined", rotation=90, ha="center",
                                va="bottom", fontsize=6, color=styles[method]["color"])
                ax.bar(positions, np.nan_to_num(values, nan=0.0), width=bar_width,
                       color=styles[method]["color"],
                       hatch="//" if styles[method]["linestyle"] == "--" else None,
                       edgecolor="white", linewidth=0.3, label=labels.get(method, method))
            ax.set_xticks(x, [f"{r}\n{p}" for r, p in groups])
            ax.set(ylabel=METRIC_LABELS.get(metric, metric), ylim=(0, 1))
            ax.grid(True, axis="y", linewidth=0.4, alpha=0.5)
        handles, names = axes[0].get_legend_handles_labels()
        fig.legend(handles, names, loc="outside lower center",
                   ncol=_legend_columns(names, width=fig_width), frameon=False)
        fig.suptitle("Area under the curve per route and pair (selected protocols)")
    return fig


def matrices_figure(matrices: Mapping[str, Mapping[str, np.ndarray]], *,
                    labels: Mapping[str, str], title: str, d_thresh: int | None = None
                    ) -> Figure:
    """Fig. 6: difference matrix ``D`` and the matrix the sequence search used, one row per
    method.

    Parameters
    ----------
    matrices : mapping
        ``{method: {"D": (R, Q), "D_hat": (R, Q), "match": (Q,) int, "truth": (Q,) int}}``;
        ``match`` (dots) and ``truth`` (``-1`` = none; a band of ``±d_thresh`` reference frames
        around it, under the dots) are overlaid on ``D_hat`` when given. Where ``D_hat`` is
        ``D`` (the method's protocol does not enhance), the right panel's title says so.
        Colours span each panel's 1st-99th percentile of finite values (dark = alike;
        non-finite cells grey), each panel with its own colour bar: the scale of ``D``
        differs between codes. Matrices with more than ``MAX_DISPLAY_SIDE`` rows or columns
        are shown strided.
    title : str
        Figure title (route and pair).
    d_thresh : int, optional
        Tolerance of a correct match, reference frames (the band's half-width); None: a line.
    """
    if not matrices:
        raise ValueError("matrices: no method to plot")
    n = len(matrices)
    height = 2.2 * n + 0.8
    row_labels = {method: f"{wrapped_label(labels.get(method, method))}\nreference frame"
                  for method in matrices}
    lines = max(label.count("\n") + 1 for label in row_labels.values())
    with plt.rc_context(STYLE):
        fig = new_figure(width=7.2, height=height, layout=None)
        # room on the left for the tick labels and every line of the longest row label
        fig.subplots_adjust(left=(0.42 + 0.15 * lines) / 7.2, right=0.93, bottom=0.4 / height,
                            top=1 - 0.75 / height, wspace=0.35, hspace=0.45)
        axes = fig.subplots(n, 2, squeeze=False)
        for row, (method, arrays) in enumerate(matrices.items()):
            same = _same_matrix(arrays["D"], arrays["D_hat"])
            for col, key in enumerate(("D", "D_hat")):
                ax = axes[row, col]
                matrix = np.asarray(arrays[key], dtype=float)
                if matrix.ndim != 2:
                    raise ValueError(f"matrices[{method!r}][{key!r}]: expected a 2-D array, "
                                     f"got shape {matrix.shape}")
                finite = matrix[np.isfinite(matrix)]
                low, high = (np.percentile(finite, [1, 99]) if finite.size else (0.0, 1.0))
                rows_, cols_ = matrix.shape
                shown = np.ma.masked_invalid(
                    matrix[::_stride(rows_), ::_stride(cols_)])  # +inf (excluded) -> grey
                image = ax.imshow(shown, aspect="auto", interpolation="nearest",
                                  cmap=_viridis_grey_bad(), vmin=low, vmax=high,
                                  extent=(-0.5, cols_ - 0.5, rows_ - 0.5, -0.5))
                bar = fig.colorbar(image, ax=ax, fraction=0.05, pad=0.02)
                bar.ax.tick_params(labelsize=6)
                if key == "D_hat":
                    _overlay_matches(ax, arrays, d_thresh=d_thresh)
                    ax.set(xlim=(-0.5, cols_ - 0.5), ylim=(rows_ - 0.5, -0.5))
                    ax.set_title(r"searched: $D$ itself (not enhanced)" if same
                                 else r"searched: $\hat{D}$ (eq. 14)", fontsize=8)
                elif row == 0:
                    ax.set_title("difference $D$ (dark = alike)", fontsize=8)
                if row == n - 1:
                    ax.set_xlabel("query frame")
                if col == 0:
                    ax.set_ylabel(row_labels[method])
        handles, names = axes[0, 1].get_legend_handles_labels()
        if handles:
            fig.legend(handles, names, loc="upper right", ncol=len(names), frameon=False,
                       markerscale=4, bbox_to_anchor=(0.97, 1 - 0.3 / height))
        fig.suptitle(title, x=0.4)
    return fig


def _same_matrix(a: np.ndarray, b: np.ndarray) -> bool:
    """``a`` and ``b`` hold the same values (NaN equal to NaN)."""
    a, b = np.asarray(a), np.asarray(b)
    return a.shape == b.shape and bool(np.array_equal(a, b, equal_nan=True))


#: Characters per line of a method label beside a 2.2-inch panel (fits its height).
LABEL_WIDTH = 26


def wrapped_label(label: str, *, width: int = LABEL_WIDTH) -> str:
    """``label`` broken at spaces into lines of at most ``width`` characters (a longer word
    keeps its own line)."""
    return textwrap.fill(label, width=width, break_long_words=False, break_on_hyphens=False)


def _stride(side: int) -> int:
    """Display stride keeping at most ``MAX_DISPLAY_SIDE`` rows or columns of a matrix."""
    return max(1, -(-side // MAX_DISPLAY_SIDE))


def _viridis_grey_bad():
    return matplotlib.colormaps["viridis"].with_extremes(bad="0.6")


def _overlay_matches(ax, arrays: Mapping[str, np.ndarray], *, d_thresh: int | None) -> None:
    """Mark the true place (a band of ``±d_thresh`` frames, or a line) and SeqSLAM's match
    (dots, on top) of every query on ``ax``."""
    if "truth" in arrays:
        truth = np.asarray(arrays["truth"])
        q = np.flatnonzero(truth >= 0)
        if d_thresh is None:  # a broad pale line, so that the dots on it stay visible
            ax.plot(q, truth[q], color="white", linewidth=3.0, alpha=0.45, label="true place")
        else:  # NaN (no true place) breaks the band
            placed = np.where(truth >= 0, truth, np.nan).astype(float)
            ax.fill_between(np.arange(truth.size), placed - d_thresh - 0.5,
                            placed + d_thresh + 0.5, color="white", alpha=0.45, linewidth=0,
                            label=f"true place ±{d_thresh}")
    if "match" in arrays:
        match = np.asarray(arrays["match"])
        q = np.flatnonzero(match >= 0)
        ax.scatter(q, match[q], s=1.5, color="tab:red", linewidths=0, label="match", zorder=3)


def reconstructions_figure(a: np.ndarray, recon_a: np.ndarray, translated_b: np.ndarray,
                           b: np.ndarray, *, condition_a: Sequence[str],
                           condition_b: Sequence[str], offset_b: Sequence[str] | None = None,
                           max_rows: int = 6) -> Figure:
    """Fig. 11: image A, its reconstruction under A's weather, the same code decoded under B's
    weather, and a real image B (the view of A's place under B's weather).

    Parameters
    ----------
    a, recon_a, translated_b, b : ndarray, uint8, shape (n, H, W, 3)
    condition_a, condition_b : sequence of str, length n
        Weather names of A and B per row.
    offset_b : sequence of str, length n, optional
        How far B's view is from A's (``"0.4 m, 3° away"``), shown on B.
    max_rows : int
        At most this many samples are shown.
    """
    images = [np.asarray(x) for x in (a, recon_a, translated_b, b)]
    n = images[0].shape[0]
    for name, image in zip(("a", "recon_a", "translated_b", "b"), images):
        if image.ndim != 4 or image.shape[0] != n or image.shape[-1] != 3:
            raise ValueError(f"{name}: expected shape (n={n}, H, W, 3), got {image.shape}")
    if len(condition_a) != n or len(condition_b) != n:
        raise ValueError(f"condition_a, condition_b: expected {n} names each")
    if offset_b is not None and len(offset_b) != n:
        raise ValueError(f"offset_b: expected {n} labels, got {len(offset_b)}")
    rows = min(n, max_rows)
    height, width = images[0].shape[1:3]
    with plt.rc_context(STYLE):
        fig = new_figure(width=6.4, height=6.4 / 4 * height / width * rows + 0.5)
        axes = fig.subplots(rows, 4, squeeze=False)
        for i in range(rows):
            titles = (f"A ({condition_a[i]})", f"De(En(A)|{condition_a[i]})",
                      f"De(En(A)|{condition_b[i]})", f"B ({condition_b[i]})")
            for j, (image, title) in enumerate(zip(images, titles)):
                ax = axes[i, j]
                ax.imshow(image[i], interpolation="nearest")
                ax.set_title(title, fontsize=7)
                ax.set_axis_off()
            if offset_b is not None:  # inside B's panel: the rows keep their spacing
                axes[i, 3].text(0.5, 0.03, f"A's place, {offset_b[i]}", fontsize=6,
                                ha="center", va="bottom", transform=axes[i, 3].transAxes,
                                color="black", bbox={"facecolor": "white", "alpha": 0.8,
                                                     "edgecolor": "none", "pad": 1.0})
        fig.suptitle("CMAL reconstructions: one code, decoded under two weathers")
    return fig


SCALE_SPLIT = 10.0  # a panel's keys whose largest |value| differ by more than this get two panels


def training_panels(log: pd.DataFrame, keys: Sequence[str], *,
                    split: float = SCALE_SPLIT) -> list[tuple[str, list[str]]]:
    """Panels of :func:`training_curves_figure`: ``(title, keys)``, one per prefix (``D/``,
    ``E/``, ...), a prefix split by scale when its keys' largest absolute values span more
    than a factor ``split`` (e.g. code norms of about 13 beside reconstruction losses of about
    0.05, which would look flat at zero on a shared axis).

    A prefix's keys are sorted by scale and cut at the widest gap (ratio of neighbouring
    scales), again in each part, until every panel spans at most ``split``. Keys that are all
    zero or NaN join the smallest panel of their prefix. Within a panel the log's order is
    kept. A split panel's title gives its largest value, e.g. ``"E (|value| <= 14)"``.
    """
    scale = {k: float(np.nanmax(np.abs(log[k].to_numpy(float)), initial=0.0)) for k in keys}
    panels: list[tuple[str, list[str]]] = []
    for prefix in dict.fromkeys(k.split("/")[0] for k in keys):
        mine = [k for k in keys if k.split("/")[0] == prefix]
        ranked = sorted((k for k in mine if scale[k] > 0), key=lambda k: -scale[k])
        groups = _cut_at_widest_gaps(ranked, scale, split) or [[]]
        groups[-1] += [k for k in mine if not scale[k] > 0]
        for group in groups:
            title = (prefix if len(groups) == 1
                     else f"{prefix} (|value| <= {scale[group[0]]:.2g})")
            panels.append((title, [k for k in mine if k in group]))
    return panels


def _cut_at_widest_gaps(ranked: list[str], scale: Mapping[str, float],
                        split: float) -> list[list[str]]:
    """``ranked`` (keys by decreasing positive scale) cut into runs spanning <= ``split``."""
    if len(ranked) < 2 or scale[ranked[0]] <= split * scale[ranked[-1]]:
        return [ranked] if ranked else []
    ratios = [scale[a] / scale[b] for a, b in zip(ranked, ranked[1:])]
    cut = 1 + int(np.argmax(ratios))
    return (_cut_at_widest_gaps(ranked[:cut], scale, split)
            + _cut_at_widest_gaps(ranked[cut:], scale, split))


#: What a logged training value measures, by kind (:func:`_value_kind`).
_KIND_LABELS = {"score": "validation score (0-1)", "fraction": "accuracy or D(x) (0-1)",
                "norm": "code L2 norm", "loss": "loss"}
#: Scores of a discriminator (its mean output on a batch), not losses.
_SCORE_NAMES = ("real", "fake", "recon", "trans", "gen_a", "gen_b")


def _value_kind(key: str) -> str:
    """``score`` (val/), ``fraction`` (accuracies, D and D_z outputs), ``norm`` or ``loss``."""
    prefix, _, name = key.rpartition("/")
    if prefix == "val":
        return "score"
    if "acc" in name or (prefix in ("D", "Dz") and name in _SCORE_NAMES):
        return "fraction"
    return "norm" if "norm" in name else "loss"


def panel_ylabel(keys: Sequence[str]) -> str:
    """What the y axis of a training panel holding ``keys`` measures (kinds joined by "; "
    when a panel mixes them)."""
    kinds = list(dict.fromkeys(_value_kind(key) for key in keys))
    return "; ".join(_KIND_LABELS[kind] for kind in kinds) or "logged value"


def training_curves_figure(log: pd.DataFrame, *, title: str,
                           kept_iteration: int | None = None) -> Figure:
    """Training logs against iteration, one panel per prefix (``D/``, ``G/``, ..., ``val/``),
    split by scale where one axis would flatten some curves (:func:`training_panels`); each y
    axis says what it measures (:func:`panel_ylabel`), iterations are whole numbers, and the
    iteration ``model.pt`` keeps is marked on every panel.

    Parameters
    ----------
    log : DataFrame
        ``iteration`` and one column per logged key (``train_log.csv``).
    kept_iteration : int, optional
        The iteration whose weights ``model.pt`` keeps (``selection.json``).
    """
    from matplotlib.ticker import MaxNLocator

    if "iteration" not in log.columns:
        raise ValueError("log: needs an 'iteration' column")
    keys = [c for c in log.columns if c != "iteration"]
    panels = training_panels(log, keys) or [("(none)", [])]
    rows, columns = _grid(len(panels), max_columns=2)
    with plt.rc_context(STYLE):
        fig = new_figure(width=4.6 * columns, height=2.3 * rows + 0.4)
        axes = np.atleast_1d(fig.subplots(rows, columns, squeeze=False)).ravel()
        for ax, (panel_title, panel_keys) in zip(axes, panels):
            for key in panel_keys:
                logged = log[["iteration", key]].dropna()  # keys logged at other cadences
                ax.plot(logged["iteration"].to_numpy(float), logged[key].to_numpy(float),
                        linewidth=0.9, marker="." if len(logged) < 30 else None,
                        label=key)
            if panel_keys and kept_iteration is not None:
                ax.axvline(kept_iteration, color="black", linestyle="--", linewidth=0.8,
                           label=f"kept: iteration {kept_iteration}")
            ax.set(title=panel_title, xlabel="iteration", ylabel=panel_ylabel(panel_keys))
            ax.xaxis.set_major_locator(MaxNLocator(integer=True))
            ax.grid(True, linewidth=0.4, alpha=0.5)
            if ax.lines:
                ax.legend(frameon=False, loc="upper left", bbox_to_anchor=(1.0, 1.0),
                          fontsize=6)
        for ax in axes[len(panels):]:
            ax.set_axis_off()
        fig.suptitle(title)
    return fig
