"""The planner on a deploy install, where torch is not installed (``pip install --no-deps spade`` next to the
``deploy`` extra's packages; docs/deployment.md).

The planner needs only numpy/scipy/scikit-image modules of ``spade.data``, ``spade.metrics`` and ``spade.maps`` (whose
package ``__init__``s import no torch) and an ONNX runtime. Where torch is not installed (:data:`LEAN`) the model
files are read by :mod:`spade.deploy.onnx_runtime` (ONNX students through onnxruntime alone), elsewhere by
:mod:`spade.models.modelfile`; the planner imports the reader's names from here.
"""

from __future__ import annotations

import importlib.util
import sys

__all__ = ["LEAN", "ModelFileError", "UnsafeModelFileError", "open_model", "robot_frame", "torch_available"]


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

if LEAN:  # ONNX students through onnxruntime alone
    from spade.deploy.onnx_runtime import ModelFileError, UnsafeModelFileError, open_model, robot_frame
else:
    from spade.models.modelfile import ModelFileError, UnsafeModelFileError, open_model, robot_frame
