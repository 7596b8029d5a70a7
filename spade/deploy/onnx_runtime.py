"""An exported ONNX student run by onnxruntime alone (no torch, no ``onnx`` package): what the planner uses on a
deploy install (:data:`spade.deploy.lean.LEAN`). The same reading of the file's SPADE metadata as
:mod:`spade.models.modelfile` (the ``spade`` entry of the ONNX ``metadata_props``, as ``python -m spade.export``
writes it), the same role and robot-frame checks, the same check that the graph is the export its metadata
describes (:mod:`spade.models.onnx_check`, torch-free), the same ONNX Runtime session (:mod:`spade.models.onnx_session`,
torch-free) and the same ``logits(states)`` call as its ``ModelRunner``.
"""

from __future__ import annotations

import json
import zipfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from spade.models.onnx_check import check_onnx_student
from spade.models.onnx_session import OnnxSession

__all__ = ["ModelFileError", "OnnxRunner", "UnsafeModelFileError", "open_model", "robot_frame"]

ENTRY_KEY = "spade"
EXPORT = "export the student with python -m spade.export ckpt_path=<student .ckpt> (on a machine with torch)"


class ModelFileError(ValueError):
    """A model file the deploy install cannot use; the message names the file and the fix."""


class UnsafeModelFileError(ModelFileError):
    """Never raised here (no pickles are read); defined so that callers catch the same names."""


class OnnxRunner:
    """``logits = runner(states)``: (N, 3, H, W) float32 -> (N, 1, H, W) float32. Attributes as
    :class:`spade.models.modelfile.ModelRunner`'s: ``path``, ``format`` (onnx), ``runtime``, ``device``, ``info``."""

    format, runtime, net = "onnx", "onnxruntime", None

    def __init__(self, path: str | Path, device: str = "cpu", threads: int | None = None,
                 role: str | None = "student", allow_unsigned: bool = False) -> None:
        self.path = Path(path).expanduser()
        if not self.path.is_file():
            raise ModelFileError(f"{self.path} does not exist; pass an ONNX student from python -m spade.export")
        if zipfile.is_zipfile(self.path) or self.path.read_bytes()[:1] == b"\x80":
            raise ModelFileError(f"{self.path} is a PyTorch checkpoint or TorchScript file, which need torch (not "
                                 f"installed here); {EXPORT} and pass the .onnx file")
        self._session = OnnxSession(self.path, device, threads, ModelFileError, EXPORT)
        self.device = self._session.device
        meta = self._session.metadata()
        if ENTRY_KEY not in meta:
            raise ModelFileError(f"{self.path} carries no '{ENTRY_KEY}' metadata, so it is not a SPADE student "
                                 f"export: {EXPORT}")
        self.info: dict[str, Any] = json.loads(meta[ENTRY_KEY])
        if role is not None and self.info.get("role") != role:
            raise ModelFileError(f"{self.path} has role {self.info.get('role')!r}, not {role!r}: pass a student export")
        check_onnx_student(self.path, self.info, self.path.read_bytes, self._session.input.shape,
                           self._session.output.shape, self, ModelFileError, allow_unsigned)

    def __call__(self, states: np.ndarray) -> np.ndarray:
        return self._session(states)

    logits = __call__

    def __repr__(self) -> str:
        return f"OnnxRunner({self.path.name}, onnx on {self.device})"


def open_model(path: str | Path, device: str = "cpu", threads: int | None = None,
               role: str | None = "student", allow_unsigned: bool = False) -> OnnxRunner:
    return OnnxRunner(path, device, threads, role, allow_unsigned)


def robot_frame(info: Mapping[str, Any], path: str | Path) -> dict[str, Any]:
    """The robot frame (``data.frame``) a model was trained in (as :func:`spade.models.modelfile.robot_frame`)."""
    data = info.get("data") or {}
    frame = data.get("frame") if isinstance(data, Mapping) else None
    if not isinstance(frame, Mapping) or frame.get("kind") != "robot":
        raise ModelFileError(f"{path} was trained on axis-aligned windows (no robot frame, data.frame): the planner "
                             "needs a robot-frame student; retrain it and export it again")
    for key in ("image_size", "resolution_m"):
        if data.get(key) is None:
            raise ModelFileError(f"{path} records a robot frame but no {key}: it was not written by SPADE")
    return dict(frame)
