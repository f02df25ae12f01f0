"""The report's tables rendered: display strings, then Markdown, CSV and LaTeX files.

A table arrives built (:mod:`cmal_lcd.reports.tables`: raw floats, or strings for text
columns). :func:`format_cells` turns values into display strings (percentages like the paper's
``34.8%``; ``–`` for a missing value), then :func:`markdown_table` and
:func:`latex_booktabs_table` lay the strings out; :func:`csv_table` writes the raw floats.
:func:`render_table` gives all three and :func:`write_table` writes them. Rendering is done by
hand (no ``tabulate`` or ``jinja2`` needed), so the output is the same on every installation.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path
from typing import Callable, Mapping, Sequence

import pandas as pd

from cmal_lcd.io import atomic_write_text

logger = logging.getLogger(__name__)

#: A missing value as shown (NaN, JSON ``null``, an empty text cell).
MISSING = "–"

Formatter = Callable[[float], str]


def format_percent(value: object, *, digits: int = 1) -> str:
    """A fraction as a percentage like the paper's (``0.348 -> "34.8%"``); NaN -> ``"–"``."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return MISSING
    return f"{100.0 * float(value):.{digits}f}%"


def format_number(value: object, *, digits: int = 3) -> str:
    """A number with ``digits`` significant digits (``"–"`` for NaN); integers stay whole."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return MISSING
    value = float(value)
    if value.is_integer() and abs(value) < 1e15:
        return f"{int(value):,}"
    return f"{value:.{digits}g}"


def format_ms(value: object) -> str:
    """Milliseconds with two decimals (``"–"`` for NaN)."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return MISSING
    return f"{float(value):.2f}"


def format_cells(table: pd.DataFrame, *, default: Formatter = format_percent,
                 columns: Mapping[object, Formatter] | None = None) -> pd.DataFrame:
    """Display strings for every cell.

    Parameters
    ----------
    table : DataFrame
        Raw values: floats (NaN = missing) or strings (kept as they are; ``""`` = missing).
    default : callable
        Formats a float cell whose column has no entry in ``columns``.
    columns : mapping, optional
        Per-column formatter, keyed by the column label.
    """
    columns = dict(columns or {})
    out = pd.DataFrame(index=table.index, columns=table.columns, dtype=object)
    for col in table.columns:
        fmt = columns.get(col, default)
        out[col] = [(value or MISSING) if isinstance(value, str) else fmt(value)
                    for value in table[col]]
    return out


def _header_text(column: object) -> str:
    return " ".join(str(part) for part in column) if isinstance(column, tuple) else str(column)


def _row_label_cells(index: pd.Index) -> list[list[str]]:
    """Row labels, one list per row; a label equal to the row above is left blank (outer
    levels only), which reads as grouping."""
    tuples = [t if isinstance(t, tuple) else (t,) for t in index]
    cells, previous = [], None
    for row in tuples:
        shown = []
        for level, value in enumerate(row):
            same_prefix = previous is not None and row[:level + 1] == previous[:level + 1]
            shown.append("" if same_prefix and level < len(row) - 1 else str(value))
        cells.append(shown)
        previous = row
    return cells


def _index_names(index: pd.Index) -> list[str]:
    return [str(name) if name is not None else "" for name in index.names]


def markdown_table(cells: pd.DataFrame, *, text_columns: Sequence[object] = ()) -> str:
    """A GitHub-flavoured Markdown table of display strings.

    Two-level columns are written ``"<route> <pair>"``; row index levels become the leading
    columns. Index levels and ``text_columns`` are left-aligned, other columns right-aligned.
    """
    header = _index_names(cells.index) + [_header_text(c) for c in cells.columns]
    align = [":--"] * cells.index.nlevels + [":--" if c in text_columns else "--:"
                                             for c in cells.columns]
    lines = ["| " + " | ".join(_escape_markdown(h) for h in header) + " |",
             "|" + "|".join(align) + "|"]
    for labels, (_, row) in zip(_row_label_cells(cells.index), cells.iterrows()):
        values = labels + [str(v) for v in row.tolist()]
        lines.append("| " + " | ".join(_escape_markdown(v) for v in values) + " |")
    return "\n".join(lines) + "\n"


def _escape_markdown(text: str) -> str:
    return text.replace("|", "\\|")


_LATEX_SPECIAL = {"\\": r"\textbackslash{}", "&": r"\&", "%": r"\%", "$": r"\$", "#": r"\#",
                  "_": r"\_", "{": r"\{", "}": r"\}", "~": r"\textasciitilde{}",
                  "^": r"\textasciicircum{}", "–": "--"}


def escape_latex(text: str) -> str:
    """``text`` with LaTeX's special characters escaped (``34.8%`` -> ``34.8\\%``)."""
    return "".join(_LATEX_SPECIAL.get(ch, ch) for ch in str(text))


def latex_booktabs_table(cells: pd.DataFrame, *, caption: str, label: str,
                         text_columns: Sequence[object] = ()) -> str:
    """A LaTeX ``table`` with a booktabs ``tabular`` of display strings.

    Two-level columns get a grouped header (``\\multicolumn`` + ``\\cmidrule``). Index levels
    and ``text_columns`` are left-aligned. Needs ``\\usepackage{booktabs}``.
    """
    n_index = cells.index.nlevels
    spec = "l" * n_index + "".join("l" if c in text_columns else "r" for c in cells.columns)
    lines = [r"\begin{table}[ht]", r"\centering",
             rf"\caption{{{escape_latex(caption)}}}", rf"\label{{{label}}}",
             rf"\begin{{tabular}}{{{spec}}}", r"\toprule"]
    grouped = isinstance(cells.columns, pd.MultiIndex) and cells.columns.nlevels == 2
    if grouped:
        groups: list[tuple[str, int]] = []
        for top, _ in cells.columns:
            if groups and groups[-1][0] == top:
                groups[-1] = (top, groups[-1][1] + 1)
            else:
                groups.append((top, 1))
        head, rules, start = [""] * n_index, [], n_index + 1
        for top, span in groups:
            head.append(rf"\multicolumn{{{span}}}{{c}}{{{escape_latex(top)}}}")
            rules.append(rf"\cmidrule(lr){{{start}-{start + span - 1}}}")
            start += span
        lines.append(" & ".join(head) + r" \\")
        lines.append(" ".join(rules))
        sub = [str(bottom) for _, bottom in cells.columns]
    else:
        sub = [_header_text(c) for c in cells.columns]
    lines.append(" & ".join(escape_latex(h) for h in _index_names(cells.index) + sub) + r" \\")
    lines.append(r"\midrule")
    for labels, (_, row) in zip(_row_label_cells(cells.index), cells.iterrows()):
        values = labels + [str(v) for v in row.tolist()]
        lines.append(" & ".join(escape_latex(v) for v in values) + r" \\")
    lines += [r"\bottomrule", r"\end{tabular}", r"\end{table}"]
    return "\n".join(lines) + "\n"


def csv_table(table: pd.DataFrame) -> str:
    """The raw table as CSV: index levels as leading columns, two-level column labels joined
    with ``/`` (``route1/foggy-rainy``), floats at full precision, NaN as an empty field."""
    flat = table.copy()
    flat.columns = ["/".join(str(p) for p in c) if isinstance(c, tuple) else str(c)
                    for c in table.columns]
    return flat.reset_index().to_csv(index=False, lineterminator="\n")


def render_table(table: pd.DataFrame, *, caption: str, label: str,
                 default: Formatter = format_percent,
                 columns: Mapping[object, Formatter] | None = None) -> dict[str, str]:
    """The three renderings of a table.

    Returns
    -------
    dict
        ``{"md": Markdown (caption sentence, then the table), "csv": raw values,
        "tex": LaTeX booktabs table}``.
    """
    cells = format_cells(table, default=default, columns=columns)
    text = text_columns(table)
    return {"md": f"{caption}\n\n{markdown_table(cells, text_columns=text)}",
            "csv": csv_table(table),
            "tex": latex_booktabs_table(cells, caption=caption, label=label, text_columns=text)}


def text_columns(table: pd.DataFrame) -> list[object]:
    """Columns of ``table`` holding text (any string cell)."""
    return [c for c in table.columns if any(isinstance(v, str) for v in table[c])]


def write_table(rendered: Mapping[str, str], stem: str | Path) -> list[Path]:
    """Write ``<stem>.<suffix>`` for every rendering of :func:`render_table`, atomically.

    Returns
    -------
    list of Path
        The files written.
    """
    stem = Path(stem)
    paths = [atomic_write_text(stem.with_name(f"{stem.name}.{suffix}"), text)
             for suffix, text in rendered.items()]
    logger.info("wrote table %s.{%s}", stem, ",".join(rendered))
    return paths
