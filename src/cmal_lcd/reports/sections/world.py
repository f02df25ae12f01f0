"""Fig. 1 (the same places under every weather) and the world map, drawn by
:mod:`cmal_lcd.reports.world_figures` from the dataset folder."""

from __future__ import annotations

from pathlib import Path
from typing import Any, NamedTuple

from cmal_lcd.reports.readme import Entry
from cmal_lcd.reports.sections.entries import figure_files, not_produced


class WorldFigure(NamedTuple):
    """One figure of this section: README title, file stem, plotting function, description."""

    title: str
    stem: str
    function: str
    description: str


#: The figures, in README order; ``function`` is looked up in ``world_figures``.
WORLD_FIGURES = (
    WorldFigure("Fig. 1: the same places under every weather", "fig01_weather_samples",
                "plot_weather_samples",
                "Test frames of one place under each weather condition, as in the paper's "
                "Fig. 1."),
    WorldFigure("World map", "world_map", "plot_world_map",
                "Training area and test routes of the dataset, seen from above."),
)


def world_figure_entry(out_dir: Path, dataset: Any, figure: WorldFigure,
                       world_figures: Any) -> Entry:
    """Draw one :class:`WorldFigure` as ``figures/<stem>.{png,pdf}``, or say why not (no such
    plotting function; a world map of a dataset that is not the procedural world)."""
    plot = getattr(world_figures, figure.function, None)
    if plot is None:
        return not_produced(figure.title, f"`cmal_lcd.reports.world_figures.{figure.function}` "
                                          "does not exist.")
    if figure.stem == "world_map" and dataset.meta.get("kind") != "gtav_weather":
        return not_produced(figure.title, f"the dataset is `{dataset.meta.get('kind')}`, not "
                                          "the procedural world: there is no map to draw.")
    paths = [out_dir / "figures" / f"{figure.stem}{suffix}" for suffix in (".png", ".pdf")]
    for path in paths:
        plot(dataset, path)
    return Entry(title=figure.title, description=figure.description,
                 files=figure_files([p for p in paths if p.is_file()], out_dir))


def world_entries(out_dir: Path, dataset: Any, *, missing: str | None = None) -> list[Entry]:
    """Fig. 1 and the world map of ``dataset`` (a :class:`cmal_lcd.data.store.Dataset`).

    Parameters
    ----------
    dataset : Dataset or None
        None when it could not be read; ``missing`` then says why
        (:func:`cmal_lcd.reports.inputs.read_figure_dataset`).
    """
    if dataset is None:
        return [not_produced(f.title, missing or "no dataset.") for f in WORLD_FIGURES]
    try:
        from cmal_lcd.reports import world_figures
    except ImportError as err:
        return [not_produced(f.title, f"the plotting code is not available ({err}).")
                for f in WORLD_FIGURES]
    return [world_figure_entry(out_dir, dataset, f, world_figures) for f in WORLD_FIGURES]
