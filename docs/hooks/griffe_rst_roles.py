"""Griffe extensions for the API reference, rewriting SPADE's docstrings before mkdocstrings parses them.

- :class:`SphinxRolesAsCode`: SPADE's docstrings cross-reference with Sphinx roles; Markdown has none, so
  mkdocstrings would print the role text. This turns ``:role:`target``` into `` `target` `` (``~`` keeps the last
  name, as Sphinx shows it).
- :class:`SharedParameters`: SPADE's ``Args:`` sections document several parameters at once, as numpydoc allows
  (``threshold, max_gap, goal_tolerance_px: ...``). Griffe's Google parser takes that line for one parameter named
  ``threshold, max_gap, goal_tolerance_px``, which no signature has, so its table showed no type and *required*
  where the signature gives defaults. This splits such an entry into one entry per name with the shared
  description, so that each gets its type and default from the signature.

Both are loaded by mkdocs.yml (``plugins.mkdocstrings...extensions``).
"""

from __future__ import annotations

import re
from typing import Any

import griffe

# The sections of a Google docstring that list parameters, and one of their entries naming several parameters:
# "name, name (type): description" (the type optional).
PARAMETER_SECTION = re.compile(r"^(?P<indent>\s*)(?:Args|Arguments|Params|Parameters|Keyword Args|Keyword Arguments|"
                               r"Other Parameters|Other Params):\s*$")
SHARED_ENTRY = re.compile(r"^(?P<indent>\s+)(?P<names>\*{0,2}\w+(?:\s*,\s*\*{0,2}\w+)+)"
                          r"(?P<rest>\s*(?:\([^)]*\))?:(?:\s.*)?)$")
ROLE = re.compile(r":(?:py:)?(?:mod|class|func|meth|data|attr|exc|obj|const):`(~?)([^`]+)`")


def _code(match: re.Match) -> str:
    target = match.group(2)
    return f"`{target.rsplit('.', 1)[-1] if match.group(1) else target}`"


def _indent(line: str) -> int:
    return len(line) - len(line.lstrip())


def _entry_end(lines: list[str], start: int, indent: int) -> int:
    """The index after the entry that begins at ``start``: its continuation lines are blank or indented deeper."""
    end = start + 1
    while end < len(lines) and (not lines[end].strip() or _indent(lines[end]) > indent):
        end += 1
    while end > start + 1 and not lines[end - 1].strip():  # trailing blank lines belong to the section
        end -= 1
    return end


def split_shared_parameters(text: str) -> str:
    """A Google docstring with every ``a, b: description`` entry of its parameter sections written as one entry
    per name (``a: description``, ``b: description``); everything else is left as it is."""
    lines = text.splitlines()
    out: list[str] = []
    section: int | None = None  # the indent of the parameter section's header, while inside one
    i = 0
    while i < len(lines):
        line = lines[i]
        if line.strip() and section is not None and _indent(line) <= section:
            section = None
        header = PARAMETER_SECTION.match(line)
        if header:
            section = len(header.group("indent"))
        entry = SHARED_ENTRY.match(line) if section is not None and not header else None
        if entry is None:
            out.append(line)
            i += 1
            continue
        end = _entry_end(lines, i, len(entry.group("indent")))
        for name in re.split(r"\s*,\s*", entry.group("names")):
            out += [f"{entry.group('indent')}{name}{entry.group('rest')}", *lines[i + 1:end]]
        i = end
    return "\n".join(out)


class SharedParameters(griffe.Extension):
    """Split the ``a, b: ...`` entries of every docstring's parameter sections, one entry per parameter."""

    def _rewrite(self, obj: Any) -> None:
        doc = getattr(obj, "docstring", None)
        if doc is not None and "," in doc.value:
            doc.value = split_shared_parameters(doc.value)

    def on_instance(self, *, obj: Any, **kwargs: Any) -> None:  # griffe 1.x
        self._rewrite(obj)

    def on_object(self, *, obj: Any, **kwargs: Any) -> None:  # griffe 2.x
        self._rewrite(obj)


class SphinxRolesAsCode(griffe.Extension):
    """Rewrite Sphinx roles in every docstring griffe loads."""

    def _rewrite(self, obj: Any) -> None:
        doc = getattr(obj, "docstring", None)
        if doc is not None and ":" in doc.value:
            doc.value = ROLE.sub(_code, doc.value)

    def on_instance(self, *, obj: Any, **kwargs: Any) -> None:  # griffe 1.x
        self._rewrite(obj)

    def on_object(self, *, obj: Any, **kwargs: Any) -> None:  # griffe 2.x
        self._rewrite(obj)
