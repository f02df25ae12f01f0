"""Training curves of every trained model, from its ``train_log.csv``."""

from __future__ import annotations

from pathlib import Path
from typing import Mapping

import pandas as pd

from cmal_lcd.reports import figures
from cmal_lcd.reports.readme import Entry
from cmal_lcd.reports.sections.entries import figure_files, not_produced


def training_entry(out_dir: Path, name: str, log: pd.DataFrame | None, *,
                   source: Path, kept_iteration: int | None = None) -> Entry:
    """``figures/training_<name>.{png,pdf}``, or why not (``log`` None: no file; no rows).

    Parameters
    ----------
    log : DataFrame or None
        ``iteration`` and one column per logged key (``D/...``, ``G/...``, ``val/...``).
    source : Path
        The log file (named when it is missing or empty).
    """
    title = f"Training curves: {name}"
    if log is None:
        return not_produced(title, f"`{source}` does not exist.")
    if log.empty:
        return not_produced(title, f"`{source}` has no rows.")
    fig = figures.training_curves_figure(log, title=f"{name}: training log",
                                         kept_iteration=kept_iteration)
    paths = figures.save_figure(fig, out_dir / "figures" / f"training_{name}")
    return Entry(title=title, description=(
        f"Every logged loss of the {name} model against iteration, grouped by module "
        f"(D = discriminator, G = decoder/generator, E = encoder, C = classifier). The "
        f"`val` panel scores the validation drives during training (mean over validation "
        f"pairs of SeqSLAM R@100P, AUC-PR and single-frame r@1; codes centred by the "
        f"training mean of their nearest condition, L2, no enhancement; iteration 0 is "
        f"the untrained model): `iterations` is chosen where it flattens. The dashed line "
        f"marks the iteration whose weights `model.pt` keeps."),
        files=figure_files(paths, out_dir))


def training_entries(out_dir: Path, logs: Mapping[str, pd.DataFrame], *,
                     sources: Mapping[str, Path],
                     selections: Mapping[str, Mapping] | None = None) -> list[Entry]:
    """One :func:`training_entry` per model of ``sources`` (``{model name: train_log.csv
    path}``, in README order); ``logs`` holds the models that have a log, ``selections`` their
    ``selection.json`` (the kept iteration)."""
    kept = {name: (selection or {}).get("iteration")
            for name, selection in (selections or {}).items()}
    return [training_entry(out_dir, name, logs.get(name), source=source,
                           kept_iteration=kept.get(name))
            for name, source in sources.items()]
