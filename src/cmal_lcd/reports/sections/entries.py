"""Helpers every section uses to turn written files into README entries (:class:`Entry`)."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

from cmal_lcd.reports import render
from cmal_lcd.reports.readme import Entry


def table_entry(rendered: dict, stem: Path, out_dir: Path, *, title: str,
                description: str) -> Entry:
    """Write a rendered table (:func:`cmal_lcd.reports.render.render_table`) as
    ``<stem>.{md,csv,tex}``; its entry inlines the Markdown table without the caption."""
    render.write_table(rendered, stem)
    files = [str(stem.relative_to(out_dir)) + f".{suffix}" for suffix in rendered]
    markdown = rendered["md"].split("\n\n", 1)[1]
    return Entry(title=title, description=description, files=files, markdown=markdown)


def figure_files(paths: Sequence[Path], out_dir: Path) -> list[str]:
    """``paths`` relative to ``out_dir`` (the README links)."""
    return [str(Path(p).relative_to(out_dir)) for p in paths]


def not_produced(title: str, reason: str) -> Entry:
    """The entry of a table or figure this run could not produce, and why."""
    return Entry(title=title, description="", missing=reason)
