"""An ONNX Runtime session for an exported student: the one set-up of every ONNX runner.

Both ONNX runners open the file here: :class:`spade.models.modelfile.ModelRunner` (with torch) and
:class:`spade.deploy.onnx_runtime.OnnxRunner` (the deploy install, without torch). One device policy
(:func:`spade.utils.devices.device_name` against onnxruntime's own providers), one thread setting, the CUDA
provider first where a CUDA device is asked for, and the graph's input and output names.

Torch-free on purpose (numpy and onnxruntime only): the deploy install imports it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from spade.utils.devices import device_name

__all__ = ["NO_CUDA_PROVIDER", "OUTPUT_NAME", "OnnxSession"]

OUTPUT_NAME = "logits"  # the output python -m spade.export names; an older or foreign graph's first output otherwise
NO_CUDA_PROVIDER = "this onnxruntime has no CUDA provider: pass device=cpu (or install onnxruntime-gpu)"


class OnnxSession:
    """An ONNX file opened by onnxruntime on ``device`` (``cpu``, ``cuda``, ``cuda:N`` or ``auto``), with at most
    ``threads`` intra-op threads; ``error`` is raised, naming the file, where the device or the file cannot be used
    (``fix`` ends that message). ``session(states)``: float32 (N, ...) in, the output as float32 out."""

    def __init__(self, path: str | Path, device: str | None, threads: int | None, error: type[Exception],
                 fix: str = "") -> None:
        try:
            import onnxruntime as ort
        except ImportError:  # pragma: no cover - depends on the installed extras
            raise ImportError("onnxruntime is needed for ONNX files: pip install -e '.[onnx]'") from None

        self.path = Path(path)
        self.device = device_name(device, "CUDAExecutionProvider" in ort.get_available_providers(), error,
                                  NO_CUDA_PROVIDER)
        options = ort.SessionOptions()
        if threads:
            options.intra_op_num_threads = int(threads)
        providers: list[Any] = ["CPUExecutionProvider"]
        if self.device.startswith("cuda"):
            index = int(self.device.split(":")[1]) if ":" in self.device else 0
            providers.insert(0, ("CUDAExecutionProvider", {"device_id": index}))
        try:
            self.session = ort.InferenceSession(str(self.path), options, providers=providers)
        except Exception as err:  # noqa: BLE001 - onnxruntime raises its own kinds on a file that is not ONNX
            raise error(f"{self.path} is not an ONNX model onnxruntime can load ({type(err).__name__})"
                        + (f"; {fix}" if fix else "")) from None
        self.input = self.session.get_inputs()[0]
        outputs = self.session.get_outputs()
        self.output = next((o for o in outputs if o.name == OUTPUT_NAME), outputs[0])

    def metadata(self) -> dict[str, str]:
        """The file's ``metadata_props`` (SPADE's export writes its ``spade`` entry there)."""
        return dict(self.session.get_modelmeta().custom_metadata_map)

    def __call__(self, states: np.ndarray) -> np.ndarray:
        x = np.ascontiguousarray(states, dtype=np.float32)
        return np.asarray(self.session.run([self.output.name], {self.input.name: x})[0], dtype=np.float32)
