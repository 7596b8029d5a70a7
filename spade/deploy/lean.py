"""The planner on a deploy install, where torch is not installed (``pip install --no-deps spade`` next to the
``deploy`` extra's packages; docs/deployment.md).

The planner needs only numpy/scipy/scikit-image modules of ``spade.data``, ``spade.metrics`` and ``spade.maps`` and an
ONNX runtime, but the ``spade.data``, ``spade.metrics`` and ``spade.models`` packages import torch, torchmetrics and
diffusers in their ``__init__``. Where torch is not installed (:data:`LEAN`), :func:`defer_package_inits` registers
those packages so that their submodules import without running the package ``__init__``; the ``__init__`` runs the
first time a name it defines is asked for (as it would have, and it fails as it would have without torch). Where
torch is installed nothing changes: the packages import as usual.
"""

from __future__ import annotations

import importlib.util
import sys
import types

__all__ = ["LEAN", "defer_package_inits", "torch_available"]


def torch_available() -> bool:
    """Whether ``import torch`` can succeed, without importing it (a ``None`` in ``sys.modules`` blocks it)."""
    if "torch" in sys.modules:
        return sys.modules["torch"] is not None
    try:
        return importlib.util.find_spec("torch") is not None
    except (ImportError, ValueError):
        return False


LEAN = not torch_available()
"""True where torch cannot be imported: the planner runs ONNX students with onnxruntime only."""


def defer_package_inits(*names: str) -> None:
    """Register packages ``names`` (not yet imported) so that importing their submodules does not run their
    ``__init__``; it runs on the first access to a name the module does not have yet."""
    for name in names:
        if name in sys.modules:
            continue
        spec = importlib.util.find_spec(name)
        if spec is None or spec.loader is None or spec.submodule_search_locations is None:
            continue
        module = importlib.util.module_from_spec(spec)
        module.__getattr__ = _run_init_on_demand(module, spec)  # type: ignore[attr-defined]
        sys.modules[name] = module


def _run_init_on_demand(module: types.ModuleType, spec: importlib.machinery.ModuleSpec):  # noqa: ANN202
    def __getattr__(attr: str):  # noqa: ANN202, N807 - PEP 562
        if attr.startswith("__"):
            raise AttributeError(f"module {module.__name__!r} has no attribute {attr!r}")
        module.__dict__.pop("__getattr__", None)
        spec.loader.exec_module(module)  # type: ignore[union-attr] - the package's own __init__, once
        try:
            return module.__dict__[attr]
        except KeyError:
            raise AttributeError(f"module {module.__name__!r} has no attribute {attr!r}") from None

    return __getattr__
