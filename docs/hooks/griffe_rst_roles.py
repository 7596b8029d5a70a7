"""Griffe extension for the API reference: the docstrings' Sphinx roles (``:class:`~spade.x.Y```) as code spans.

SPADE's docstrings cross-reference with Sphinx roles; Markdown has none, so mkdocstrings would print the role
text. This turns ``:role:`target``` into `` `target` `` (``~`` keeps the last name, as Sphinx shows it) before
the docstrings are rendered. Loaded by mkdocs.yml (``plugins.mkdocstrings...extensions``).
"""

from __future__ import annotations

import re
from typing import Any

import griffe

ROLE = re.compile(r":(?:py:)?(?:mod|class|func|meth|data|attr|exc|obj|const):`(~?)([^`]+)`")


def _code(match: re.Match) -> str:
    target = match.group(2)
    return f"`{target.rsplit('.', 1)[-1] if match.group(1) else target}`"


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
