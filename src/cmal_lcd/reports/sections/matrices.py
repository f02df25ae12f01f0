"""Fig. 6: the difference and enhanced matrices of every method, one figure per pair."""

from __future__ import annotations

from pathlib import Path
from typing import Iterable, Mapping

import numpy as np

from cmal_lcd.reports import figures
from cmal_lcd.reports.readme import Entry
from cmal_lcd.reports.sections.entries import figure_files, not_produced


def matrix_entry(out_dir: Path, *, route: str, pair: str,
                 found: Mapping[str, Mapping[str, np.ndarray]], absent: list[str],
                 labels: Mapping[str, str], d_thresh: int | None = None) -> Entry:
    """``figures/fig06_matrices_<route>_<pair>.{png,pdf}``, or why not when no method saved
    its matrices.

    Parameters
    ----------
    found : mapping
        ``{method: {"D", "D_hat": (n_reference, n_query), "match", "truth": (n_query,)}}``
        (:class:`cmal_lcd.reports.inputs.PairMatrices`).
    absent : list of str
        Files looked for and not found (named in the entry).
    d_thresh : int, optional
        ``matching.d_thresh``: the half-width of the true-place band.
    """
    title = f"Fig. 6: difference and enhanced matrices, {route} {pair}"
    if not found:
        return not_produced(title, "no difference matrices were saved by the evaluate stage ("
                                   + ", ".join(absent) + ")")
    fig = figures.matrices_figure(found, labels=labels, d_thresh=d_thresh,
                                  title=f"{route} {pair}: rows = reference, columns = query")
    paths = figures.save_figure(fig, out_dir / "figures" / f"fig06_matrices_{route}_{pair}",
                                png_dpi=100)
    note = f" Missing for: {', '.join(absent)}." if absent else ""
    return Entry(
        title=title,
        description="Left: the frame-to-frame difference matrix D of the normalised codes "
                    "(dark = alike); right: the matrix the sequence search used (after "
                    "eq. 14 only when the method's selected protocol enhances; its title says "
                    "which), with the true place (a white band of ±D_thresh frames, the "
                    "matches counted correct; a pale line where a ground-truth file lists the "
                    "right frames) "
                    "and SeqSLAM's matches (red dots); a clean diagonal means the code "
                    "recognises places across the weather change. Each panel has its own "
                    "colour scale (1st-99th percentile)." + note,
        files=figure_files(paths, out_dir))


def matrix_entries(out_dir: Path, matrices: Iterable, *,
                   labels: Mapping[str, str], d_thresh: int | None = None) -> list[Entry]:
    """One :func:`matrix_entry` per item of ``matrices``
    (:class:`cmal_lcd.reports.inputs.PairMatrices`: ``route``, ``pair``, ``found``,
    ``absent``), consumed one at a time."""
    return [matrix_entry(out_dir, route=m.route, pair=m.pair, found=m.found, absent=m.absent,
                         labels=labels, d_thresh=d_thresh) for m in matrices]
