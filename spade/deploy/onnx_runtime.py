"""An exported ONNX student run by onnxruntime alone (no torch, no ``onnx`` package): what the planner uses on a
deploy install (:data:`spade.deploy.lean.LEAN`). The same reading of the file's SPADE metadata as
:mod:`spade.models.modelfile` (the ``spade`` entry of the ONNX ``metadata_props``, as ``python -m spade.export``
writes it), the same role and robot-frame checks, the same check that the graph is the export its metadata
describes (:mod:`spade.models.onnx_check`, torch-free), and the same ``logits(states)`` call as its ``ModelRunner``.
"""

from __future__ import annotations

import json
import zipfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from spade.deploy.lean import LEAN, defer_package_inits

if LEAN:  # spade.models' __init__ imports torch: only its torch-free onnx_check is used here
    defer_package_inits("spade.models")

from spade.models.onnx_check import check_onnx_student  # noqa: E402 - after the deploy install's package set-up
from spade.utils.devices import device_name  # noqa: E402

__all__ = ["ModelFileError", "OnnxRunner", "UnsafeModelFileError", "open_model", "robot_frame"]

ENTRY_KEY, OUTPUT_NAME = "spade", "logits"
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
                 role: str | None = "student") -> None:
        import onnxruntime as ort

        self.path = Path(path).expanduser()
        if not self.path.is_file():
            raise ModelFileError(f"{self.path} does not exist; pass an ONNX student from python -m spade.export")
        if zipfile.is_zipfile(self.path) or self.path.read_bytes()[:1] == b"\x80":
            raise ModelFileError(f"{self.path} is a PyTorch checkpoint or TorchScript file, which need torch (not "
                                 f"installed here); {EXPORT} and pass the .onnx file")
        self.device = _device(device, ort.get_available_providers())
        options = ort.SessionOptions()
        if threads:
            options.intra_op_num_threads = int(threads)
        providers: list[Any] = ["CPUExecutionProvider"]
        if self.device.startswith("cuda"):
            index = int(self.device.split(":")[1]) if ":" in self.device else 0
            providers.insert(0, ("CUDAExecutionProvider", {"device_id": index}))
        try:
            self._session = ort.InferenceSession(str(self.path), options, providers=providers)
        except Exception as err:  # noqa: BLE001 - onnxruntime raises its own kinds on a file that is not ONNX
            raise ModelFileError(f"{self.path} is not an ONNX model onnxruntime can load ({type(err).__name__}); "
                                 f"{EXPORT}") from None
        meta = self._session.get_modelmeta().custom_metadata_map
        if ENTRY_KEY not in meta:
            raise ModelFileError(f"{self.path} carries no '{ENTRY_KEY}' metadata, so it is not a SPADE student "
                                 f"export: {EXPORT}")
        self.info: dict[str, Any] = json.loads(meta[ENTRY_KEY])
        if role is not None and self.info.get("role") != role:
            raise ModelFileError(f"{self.path} has role {self.info.get('role')!r}, not {role!r}: pass a student export")
        self._input = self._session.get_inputs()[0].name
        outputs = [o.name for o in self._session.get_outputs()]
        self._output = OUTPUT_NAME if OUTPUT_NAME in outputs else outputs[0]
        output = next(o for o in self._session.get_outputs() if o.name == self._output)
        check_onnx_student(self.path, self.info, self.path.read_bytes, self._session.get_inputs()[0].shape,
                           output.shape, self, ModelFileError)

    def __call__(self, states: np.ndarray) -> np.ndarray:
        x = np.ascontiguousarray(states, dtype=np.float32)
        return np.asarray(self._session.run([self._output], {self._input: x})[0], dtype=np.float32)

    logits = __call__

    def __repr__(self) -> str:
        return f"OnnxRunner({self.path.name}, onnx on {self.device})"


def _device(device: str | None, providers: list[str]) -> str:
    return device_name(device, "CUDAExecutionProvider" in providers, ModelFileError,
                       "this onnxruntime has no CUDA provider: pass device=cpu (or install onnxruntime-gpu)")


def open_model(path: str | Path, device: str = "cpu", threads: int | None = None,
               role: str | None = "student") -> OnnxRunner:
    return OnnxRunner(path, device, threads, role)


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
