"""Fig. 11: CMAL's reconstructions and weather translations of held-out training frames
(computed by :mod:`cmal_lcd.reports.reconstructions` from ``models/cmal/model.pt``)."""

from __future__ import annotations

from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from cmal_lcd.reports import figures
from cmal_lcd.reports.readme import Entry
from cmal_lcd.reports.sections.entries import figure_files, not_produced

TITLE = "Fig. 11: reconstructions"


def condition_names(values: np.ndarray, conditions: Sequence[str] | None) -> list[str]:
    """Weather names of ``values``: integer indices looked up in ``conditions`` (as text when
    out of range or without ``conditions``), anything else as text."""
    values = np.asarray(values)
    if np.issubdtype(values.dtype, np.integer) and conditions:
        return [conditions[int(v)] if 0 <= int(v) < len(conditions) else str(v) for v in values]
    return [str(v) for v in values]


def reconstruction_entry(out_dir: Path, arrays: Mapping[str, np.ndarray] | None, *,
                         missing: str | None, conditions: Sequence[str] | None) -> Entry:
    """``figures/fig11_reconstructions.{png,pdf}``, or ``missing`` when ``arrays`` is None.

    Parameters
    ----------
    arrays : mapping or None
        ``a``, ``recon_a``, ``translated_b``, ``b``: ``uint8 (n, H, W, 3)``;
        ``condition_a``, ``condition_b``: ``(n,)`` names or indices into ``conditions``
        (:func:`cmal_lcd.reports.inputs.compute_reconstructions`).
    missing : str or None
        Why ``arrays`` is None (Markdown, one sentence).
    conditions : sequence of str, optional
        ``dataset.json``'s condition names.
    """
    if arrays is None:
        return not_produced(TITLE, missing or "no reconstructions were computed.")
    fig = figures.reconstructions_figure(
        arrays["a"], arrays["recon_a"], arrays["translated_b"], arrays["b"],
        condition_a=condition_names(arrays["condition_a"], conditions),
        condition_b=condition_names(arrays["condition_b"], conditions),
        offset_b=([str(v) for v in arrays["offset_b"]] if "offset_b" in arrays else None))
    paths = figures.save_figure(fig, out_dir / "figures" / "fig11_reconstructions")
    return Entry(title=TITLE, description=(
        "Each row: a training frame A held out of training, CMAL's reconstruction of its code "
        "under A's weather, the same code decoded under another weather B, and a real training "
        "frame under B: the view of A's place (the nearest training frame of B's weather whose "
        "heading is within 30° of A's; its distance and turn from A are printed on it); a good "
        "model keeps the scene and changes only the weather."), files=figure_files(paths, out_dir))
