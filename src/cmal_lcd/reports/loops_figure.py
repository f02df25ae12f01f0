"""The figure of ``cmal-lcd loops``: trajectory (with poses) and self-difference matrix."""

from __future__ import annotations

from pathlib import Path

def plot_loops(path, *, matrix, shown, n_allowed, match, detected, xy=None, correct=None,
               truth=None, title=None, matrix_label="self-difference") -> Path:
    """The loop closure figure: trajectory (with poses) and the self-difference matrix.

    Parameters
    ----------
    path : path-like
        ``.png`` or ``.pdf``.
    matrix : numpy.ndarray
        ``(M, M)`` matrix of the frames ``shown`` (rows = matched frame, columns = query),
        ``+inf`` in the exclusion zone.
    shown : numpy.ndarray
        ``int (M,)`` frame indices of the matrix's rows and columns.
    n_allowed : numpy.ndarray
        ``int (N,)`` exclusion limits; the zone ``r >= n_allowed[q]`` is shaded.
    match, detected : numpy.ndarray
        ``int (N,)`` matches and ``bool (N,)`` listed loop closures.
    xy : numpy.ndarray, optional
        ``(N, 2)`` positions; adds the trajectory panel.
    correct, truth : numpy.ndarray, optional
        ``bool (N,)`` correct matches and ``int (N,)`` nearest revisits (-1: none).
    """
    import numpy as np
    from matplotlib.figure import Figure

    from cmal_lcd.reports.plots import _save

    panels = 2 if xy is not None else 1
    fig = Figure(figsize=(5.2 * panels, 4.6))
    axes = np.atleast_1d(fig.subplots(1, panels))
    q = np.flatnonzero(detected)
    if xy is not None:
        _plot_trajectory(axes[0], xy, q, correct=correct, truth=truth)
    _plot_self_difference(fig, axes[-1], matrix, n_allowed=n_allowed, match=match, q=q,
                          matrix_label=matrix_label)
    if title:
        fig.suptitle(title, fontsize="medium")
    fig.tight_layout()
    return _save(fig, path)


def _plot_trajectory(ax, xy, q, *, correct, truth) -> None:
    """The trajectory ``xy (N, 2)``: frames with a revisit (``truth int (N,)``), and the listed
    closures ``q`` as correct circles or false crosses (``correct bool (N,)``)."""
    import numpy as np

    ax.plot(xy[:, 0], xy[:, 1], color="0.7", lw=1, zorder=1)
    if truth is not None:
        rev = np.flatnonzero(truth >= 0)
        ax.scatter(xy[rev, 0], xy[rev, 1], s=60, c="tab:blue", alpha=0.25, linewidths=0,
                   label="frame with a revisit", zorder=2)
    good = q[correct[q]] if correct is not None else q[:0]
    bad = np.setdiff1d(q, good)
    # a revisited place holds frames of several passes: circles and crosses stay visible
    ax.scatter(xy[good, 0], xy[good, 1], s=28, facecolors="none", edgecolors="tab:green",
               linewidths=1.2, label="correct loop closure", zorder=3)
    ax.scatter(xy[bad, 0], xy[bad, 1], s=22, c="tab:red", marker="x", linewidths=1.0,
               label="false loop closure", zorder=4)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title("trajectory", fontsize="medium")
    ax.legend(loc="best", fontsize="x-small", markerscale=2)


def _plot_self_difference(fig, ax, matrix, *, n_allowed, match, q, matrix_label: str) -> None:
    """The ``(M, M)`` matrix over ``N = len(match)`` frames, the exclusion zone shaded below
    ``n_allowed int (N,)`` and the listed closures ``q`` at their ``match``."""
    import numpy as np
    from matplotlib.lines import Line2D

    from cmal_lcd.reports.plots import _grey_bad_cmap

    N = len(match)
    shown_matrix = np.ma.masked_invalid(np.asarray(matrix, dtype=np.float64))
    extent = (-0.5, N - 0.5, N - 0.5, -0.5)
    image = ax.imshow(shown_matrix, aspect="auto", interpolation="nearest",
                      cmap=_grey_bad_cmap(), origin="upper", extent=extent)
    fig.colorbar(image, ax=ax, fraction=0.046, pad=0.03)
    qs = np.arange(N)
    ax.fill_between(qs, np.asarray(n_allowed, float) - 0.5, N - 0.5, step="mid",
                    color="0.35", alpha=0.35, linewidth=0, zorder=2)
    ax.scatter(q, match[q], s=max(2.0, 600.0 / max(N, 1)), c="red", linewidths=0, zorder=3)
    ax.set_xlim(-0.5, N - 0.5)
    ax.set_ylim(N - 0.5, -0.5)
    ax.set_xlabel("query frame")
    ax.set_ylabel("matched (older) frame")
    ax.set_title(matrix_label, fontsize="medium")
    ax.legend(handles=[Line2D([], [], color="0.35", alpha=0.6, lw=6, label="exclusion zone"),
                       Line2D([], [], color="red", marker="o", ls="", ms=3, label="loop closure")],
              loc="lower left", fontsize="x-small")
