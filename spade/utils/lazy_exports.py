"""A package's names imported on first use (PEP 562's module ``__getattr__``), so that a light module of the
package (torch-free, Lightning-free) can be imported without the heavy ones its ``__init__`` re-exports."""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from typing import Any


def lazy_exports(package: str, homes: Mapping[str, str], namespace: dict[str, Any]) -> Callable[[str], Any]:
    """The ``__getattr__`` of ``package``: a name of ``homes`` (name -> module of the package) is imported from its
    module on first use and kept in ``namespace`` (the package's ``globals()``), so the next use is a plain lookup;
    any other name is an ``AttributeError``, as for a module without one.

    In the package's ``__init__``: ``__getattr__ = lazy_exports(__name__, _HOMES, globals())``.
    """

    def __getattr__(name: str) -> Any:
        home = homes.get(name)
        if home is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(f"{package}.{home}"), name)
        namespace[name] = value
        return value

    return __getattr__
