"""Readability checks on the artists a matplotlib figure actually draws.

Shared by the figure tests: each function asserts one rule a reader relies on and names the
axes and artist that break it. They look at what is drawn (after ``fig.canvas.draw()``), not
at the data handed in, so a NaN curve, an all-grey matrix or bars wider than their group fail.
"""

from __future__ import annotations

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.image import AxesImage
from matplotlib.patches import Rectangle


def drawn(fig: Figure) -> Figure:
    """Lay out and draw ``fig`` (text extents and constrained layout need a draw); a figure
    made without pyplot gets the Agg canvas the report saves with."""
    if not isinstance(fig.canvas, FigureCanvasAgg):
        FigureCanvasAgg(fig)
    fig.canvas.draw()
    return fig


def data_axes(fig: Figure) -> list:
    """Axes that show something (visible axis frame or an image); legends-only axes excluded."""
    return [ax for ax in fig.axes if ax.get_visible() and (ax.axison or ax.get_images())]


def bars(ax) -> list[Rectangle]:
    """The bar rectangles of ``ax`` (patches of its bar containers)."""
    return [patch for container in ax.containers for patch in container.patches]


def assert_every_axes_has_finite_data(fig: Figure) -> None:
    """Every visible axes draws at least one artist with finite data: a line with a finite
    point, a bar of finite height, a scatter offset or an image with finite, not all equal
    (or all masked) values."""
    axes = data_axes(fig)
    assert axes, "the figure has no visible axes"
    for ax in axes:
        name = ax.get_title() or ax.get_ylabel() or repr(ax)
        found = False
        for line in ax.lines:
            x = np.asarray(line.get_xdata(), float)
            y = np.asarray(line.get_ydata(), float)
            assert len(x) == len(y), f"{name}: line {line.get_label()!r} has {len(x)} x, {len(y)} y"
            if np.any(np.isfinite(x) & np.isfinite(y)):
                found = True
        for patch in bars(ax):
            assert np.isfinite(patch.get_height()), f"{name}: bar of non-finite height"
            found = True
        for collection in ax.collections:
            offsets = np.asarray(collection.get_offsets(), float)
            if offsets.size and np.isfinite(offsets).all(axis=1).any():
                found = True
        for image in ax.get_images():
            assert isinstance(image, AxesImage)
            values = np.ma.masked_invalid(np.ma.asarray(image.get_array(), dtype=float))
            shown = values.compressed()
            assert shown.size, f"{name}: image with no finite value (all grey)"
            if values.ndim == 2:  # colour-mapped: the colours span most of the map
                colours = np.clip(image.norm(shown), 0, 1)
                assert np.ptp(colours) > 0.5, (
                    f"{name}: colour-mapped image spans {np.ptp(colours):.0%} of its colour map "
                    f"(limits {image.get_clim()})")
            found = True
        assert found, f"{name}: no finite data drawn"


def legend_texts(fig: Figure) -> list[str]:
    """Texts of every legend of the figure and of its axes."""
    legends = list(fig.legends) + [ax.get_legend() for ax in fig.axes if ax.get_legend()]
    return [t.get_text() for legend in legends for t in legend.get_texts()]


def assert_legend_names(fig: Figure, names) -> None:
    """Each of ``names`` appears in a legend, exactly once across the figure legends."""
    texts = legend_texts(fig)
    for name in names:
        assert name in texts, f"legend lacks {name!r}; it shows {texts}"


def _overlap(a, b, *, pad: float = 0.0) -> bool:
    return (a.x0 < b.x1 - pad and b.x0 < a.x1 - pad and a.y0 < b.y1 - pad and b.y0 < a.y1 - pad)


def assert_tick_labels_do_not_overlap(fig: Figure) -> None:
    """On every axis of every axes, no two visible, non-empty tick labels overlap on screen."""
    drawn(fig)
    renderer = fig.canvas.get_renderer()
    for ax in data_axes(fig):
        for axis in (ax.xaxis, ax.yaxis):
            labels = [t for t in axis.get_ticklabels() if t.get_visible() and t.get_text()]
            boxes = [t.get_window_extent(renderer) for t in labels]
            for i in range(len(boxes)):
                for j in range(i + 1, len(boxes)):
                    assert not _overlap(boxes[i], boxes[j], pad=0.5), (
                        f"{ax.get_title() or ax.get_ylabel()}: tick labels "
                        f"{labels[i].get_text()!r} and {labels[j].get_text()!r} overlap")


def assert_axis_labels_do_not_overlap(fig: Figure) -> None:
    """No two visible, non-empty axis labels (x or y, of any axes) overlap on screen: a long
    y label of one panel must not run into the next panel's."""
    drawn(fig)
    renderer = fig.canvas.get_renderer()
    labels = [label for ax in data_axes(fig) for label in (ax.xaxis.label, ax.yaxis.label)
              if label.get_visible() and label.get_text()]
    boxes = [label.get_window_extent(renderer) for label in labels]
    for i in range(len(boxes)):
        for j in range(i + 1, len(boxes)):
            assert not _overlap(boxes[i], boxes[j], pad=0.5), (
                f"axis labels {labels[i].get_text()!r} and {labels[j].get_text()!r} overlap")


def assert_text_inside_the_figure(fig: Figure) -> None:
    """Nothing a reader should see is cut off at an edge: every visible axes with all it draws
    (titles, axis and tick labels, legend; ``Axes.get_tightbbox``), the figure's own texts
    (suptitle) and legends lie within the saved canvas."""
    drawn(fig)
    renderer = fig.canvas.get_renderer()
    canvas = fig.bbox
    boxes = [(f"axes {ax.get_title() or ax.get_ylabel()!r}", ax.get_tightbbox(renderer))
             for ax in fig.axes if ax.get_visible()]
    boxes += [(f"text {t.get_text()!r}", t.get_window_extent(renderer))
              for t in fig.texts if t.get_visible() and t.get_text().strip()]
    boxes += [("figure legend", legend.get_window_extent(renderer)) for legend in fig.legends]
    for name, box in boxes:
        if box is None:
            continue
        assert (box.x0 >= canvas.x0 - 1 and box.x1 <= canvas.x1 + 1 and box.y0 >= canvas.y0 - 1
                and box.y1 <= canvas.y1 + 1), (
            f"{name} runs outside the figure ({box} not within {canvas})")


def assert_bars_do_not_overlap(ax) -> None:
    """No two bars of ``ax`` share any width, and each group of bars sits within half a tick
    spacing of its tick (so a reader can tell which group a bar belongs to)."""
    rects = sorted(bars(ax), key=lambda b: b.get_x())
    for left, right in zip(rects, rects[1:]):
        assert left.get_x() + left.get_width() <= right.get_x() + 1e-9, (
            f"bars at x={left.get_x():.3f} (width {left.get_width():.3f}) and "
            f"x={right.get_x():.3f} overlap")
    ticks = np.asarray(ax.get_xticks(), float)
    if len(ticks) > 1 and rects:
        half = np.min(np.diff(ticks)) / 2
        for rect in rects:
            centre = rect.get_x() + rect.get_width() / 2
            tick = ticks[np.argmin(np.abs(ticks - centre))]
            assert tick - half <= rect.get_x() and rect.get_x() + rect.get_width() <= tick + half, (
                f"bar [{rect.get_x():.3f}, {rect.get_x() + rect.get_width():.3f}] leaves the "
                f"group of tick {tick}")


def assert_readable(fig: Figure, *, legend: list[str] | None = None) -> None:
    """All the checks: finite data, legend names, tick and axis labels, text within the
    figure, bars."""
    drawn(fig)
    assert_every_axes_has_finite_data(fig)
    if legend is not None:
        assert_legend_names(fig, legend)
    assert_tick_labels_do_not_overlap(fig)
    assert_axis_labels_do_not_overlap(fig)
    assert_text_inside_the_figure(fig)
    for ax in data_axes(fig):
        assert_bars_do_not_overlap(ax)
