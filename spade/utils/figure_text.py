"""Titles that fit their place in a matplotlib figure: wrapped at spaces, then set smaller, never cut.

A panel's title is as wide as its text, whatever the panel's width: a scenario name or a long reason runs into the
next panel's title or past the figure's edge, where the saved picture cuts it. :func:`fit_text` measures the text
with the figure's renderer and wraps it, at spaces and after a slash (a scenario's ``site/L007``), into at most
``max_lines`` lines no wider than the room given; when that is not enough it tries smaller sizes down to
``min_fontsize``, and at that size breaks a word that is still too long, so the whole text is always shown.
"""

from __future__ import annotations

import re
from typing import Any

__all__ = ["fit_text"]


def _width(text: Any, renderer: Any, line: str) -> float:
    text.set_text(line)
    return float(text.get_window_extent(renderer).width)


def _wrap(text: Any, renderer: Any, paragraph: str, width_px: float, hard: bool) -> list[str]:
    """``paragraph`` greedily wrapped at spaces and after slashes to ``width_px`` at the text's current size; with
    ``hard``, a word wider than the room is broken between characters."""
    lines: list[str] = []
    current = ""
    pieces = [(piece, k == 0) for word in paragraph.split()
              for k, piece in enumerate(re.findall(r"[^/]*/|[^/]+", word))]  # (piece, whether a space precedes)
    for word, after_space in pieces:
        candidate = (f"{current} {word}" if after_space else current + word) if current else word
        if _width(text, renderer, candidate) <= width_px:
            current = candidate
            continue
        if current:
            lines.append(current)
        current = word
        while hard and len(current) > 1 and _width(text, renderer, current) > width_px:
            cut = len(current) - 1
            while cut > 1 and _width(text, renderer, current[:cut]) > width_px:
                cut -= 1
            lines.append(current[:cut])
            current = current[cut:]
    if current:
        lines.append(current)
    return lines or [""]


def fit_text(text: Any, renderer: Any, width_px: float, height_px: float, max_lines: int = 3,
             min_fontsize: float = 6.0) -> int:
    """Wrap and shrink the matplotlib ``text`` (its current string and size) until it is at most ``width_px`` wide
    and ``height_px`` high (display pixels) in at most ``max_lines`` lines, keeping the line breaks it has; returns
    the number of lines used. The largest size that fits wins; at ``min_fontsize`` long words are broken."""
    paragraphs = text.get_text().split("\n")
    size = float(text.get_fontsize())
    while True:
        text.set_fontsize(size)
        last = size <= min_fontsize
        lines = [line for p in paragraphs for line in _wrap(text, renderer, p, width_px, hard=last)]
        text.set_text("\n".join(lines))
        box = text.get_window_extent(renderer)
        if last or (len(lines) <= max_lines and box.width <= width_px and box.height <= height_px):
            return len(lines)
        size = max(min_fontsize, size - 1.0)
