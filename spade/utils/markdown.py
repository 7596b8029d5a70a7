"""The one Markdown table writer of SPADE's pages and descriptions (results pages, the bench's report, a run's
description in the MLflow UI)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

__all__ = ["collapsed", "markdown_table", "number_table"]


def markdown_table(header: Sequence[Any], rows: Sequence[Sequence[Any]], align: str = "", padded: bool = False
                   ) -> list[str]:
    """A Markdown table's lines: the header, its rule and one line per row (cells written with ``str``).

    ``align`` gives each column's alignment, ``l`` or ``r`` (``---`` or ``---:``; columns past its end are ``l``).
    ``padded`` pads the cells to their column's width (the first column left-aligned, the rest right-aligned), for
    a table read as plain text, as the MLflow UI shows a description before rendering it.
    """
    cells = [[str(c) for c in header], *([str(c) for c in row] for row in rows)]
    if padded:
        widths = [max(len(r[i]) for r in cells) for i in range(len(cells[0]))]

        def line(row: list[str]) -> str:
            return "| " + " | ".join(c.ljust(w) if i == 0 else c.rjust(w)
                                     for i, (c, w) in enumerate(zip(row, widths))) + " |"

        rule = "|" + "|".join(("-" * (w + 2)) if i == 0 else ("-" * (w + 1) + ":") for i, w in enumerate(widths)) + "|"
        return [line(cells[0]), rule, *(line(r) for r in cells[1:])]
    rule = "|" + "".join("---:|" if align[i:i + 1] == "r" else "---|" for i in range(len(cells[0])))
    return ["| " + " | ".join(r) + " |" for r in cells[:1]] + [rule] + ["| " + " | ".join(r) + " |" for r in cells[1:]]


def collapsed(title: str, lines: Sequence[str]) -> list[str]:
    """``lines`` in a block the docs site shows closed (pymdownx.details), under ``title``."""
    return [f'??? note "{title}"', "", *(f"    {line}" if line else "" for line in lines)]


def number_table(header: list[str], rows: list[list[Any]]) -> str:
    """:func:`markdown_table` of measured numbers, each float to 3 significant digits (whole numbers from 100 on)."""

    def cell(v: Any) -> str:
        if isinstance(v, float):
            return f"{v:,.3g}" if abs(v) < 100 else f"{v:,.0f}"
        return str(v)

    return "\n".join(markdown_table(header, [[cell(v) for v in row] for row in rows]))
