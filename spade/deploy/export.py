"""Export a trained student to ONNX or TorchScript with what a deployment needs to feed it, checked against PyTorch.

The exported model maps ``state`` float32 (N, 3, H, W) (occupancy code * 0.5, start disc, goal disc; N dynamic)
to ``logits`` float32 (N, 1, H, W), before the sigmoid. It carries the JSON metadata

    {"role": "student", "config": <net.config>, "data": {"image_size": [H, W], "resolution_m": ...,
     "input_encoding": ...}, "source_checkpoint": ..., "torch_version": ..., "opset": ..., "format": ...}

as the ONNX ``metadata_props`` entry ``spade``, or as the TorchScript extra file ``spade.json``;
:func:`read_metadata` reads either back.

ONNX goes through ``torch.onnx.export(..., dynamo=False)``, the TorchScript-based exporter. Since torch 2.9 the
default is the torch.export-based exporter, which needs the ``onnxscript`` package; the student is a static
convolutional network that tracing captures exactly, and the legacy path needs only ``onnx``, so it is used (its
deprecation warnings are silenced here). TorchScript (``torch.jit.trace`` + ``freeze``) is deprecated in torch 2.x
as well but still the format C++ LibTorch deployments load.
"""

from __future__ import annotations

import json
import os
import warnings
import zipfile
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

FORMATS = ("onnx", "torchscript")
SUFFIXES = {"onnx": ".onnx", "torchscript": ".pt"}
RUNTIMES = {"onnx": "onnxruntime", "torchscript": "torchscript"}
METADATA_KEY = "spade"
TORCHSCRIPT_METADATA_FILE = "spade.json"
INPUT_NAME = "state"
OUTPUT_NAME = "logits"
DEFAULT_OPSET = 17
DEFAULT_INPUT_ENCODING = "occupancy code * 0.5 (unknown 0, free 0.5, occupied 1), start, goal"
"""What :meth:`spade.training.base.PathPlanningModule.on_save_checkpoint` records as ``input_encoding``."""
DEFAULT_TOLERANCE = 1e-3
"""Largest max |logit difference| accepted between the export and PyTorch (float32 reorderings give ~1e-6)."""


class ExportError(ValueError):
    """A checkpoint, option or file that cannot be exported or read; the message names the fix."""


@dataclass
class ExportReport:
    """What :func:`export_student` wrote and measured."""

    out_path: Path
    format: str
    max_abs_diff: float  # max |logits(export) - logits(PyTorch)| over a parity batch
    parity_batch: int
    latency_ms: dict[str, float]  # median ms per call: eager_b<N>, <runtime>_b<N>
    metadata: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        out = asdict(self)
        out["out_path"] = str(self.out_path)
        return out

    def summary(self) -> str:
        data = self.metadata.get("data") or {}
        lines = [
            f"exported {self.metadata.get('config', {}).get('preset')} student to {self.out_path} ({self.format})",
            f"window: {data.get('image_size')} px at {data.get('resolution_m')} m/px; input: {data.get('input_encoding')}",
            f"parity: max |logit difference| vs PyTorch = {self.max_abs_diff:.3g} over a batch of {self.parity_batch}",
        ]
        lines += [f"latency {k}: {v:.2f} ms" for k, v in self.latency_ms.items()]
        return "\n".join(lines)


# -- checkpoints -----------------------------------------------------------------------------------------------
def load_student_checkpoint(ckpt_path: str | Path) -> tuple[nn.Module, dict[str, Any]]:
    """The student network of a checkpoint (eval mode, on the CPU) and its ``checkpoint["spade"]`` entry.

    The network is rebuilt from the stored ``config``, so neither the LightningModule nor a guidance expert is
    needed (a Cond-DBC student's checkpoint names an expert checkpoint that a deployment machine does not have).
    """
    from spade.models import model_from_config

    path = Path(ckpt_path).expanduser()
    if not path.is_file():
        raise FileNotFoundError(
            f"ckpt_path={path} does not exist; pass a student checkpoint written by python -m spade.train "
            "(checkpoints/*.ckpt in the run's output folder, or the MLflow artifacts)"
        )
    checkpoint = torch.load(path, map_location="cpu", weights_only=False)
    info = checkpoint.get("spade") if isinstance(checkpoint, dict) else None
    if not info:
        raise ExportError(f"{path} is not a SPADE checkpoint (no 'spade' entry); pass one written by python -m spade.train")
    role = info.get("role")
    if role != "student":
        raise ExportError(
            f"{path} has role {role!r}, not 'student': diffusion experts are a training-time tool and are not exported; "
            "pass a student checkpoint (a BC / DBC / Cond-DBC run, e.g. +experiment=t1_medium_conddbc_L)"
        )
    net = model_from_config(dict(info["config"]))
    state = checkpoint.get("state_dict") or {}
    weights = {k[len("net."):]: v for k, v in state.items() if k.startswith("net.")} or state
    try:
        net.load_state_dict(weights)
    except RuntimeError as err:
        raise ExportError(f"{path}: its weights do not fit the student its config describes ({err})") from None
    return net.eval(), dict(info)


def window_metadata(info: dict[str, Any], image_size: int | Sequence[int] | None = None,
                    resolution_m: float | None = None, input_encoding: str | None = None,
                    source: str = "the checkpoint") -> dict[str, Any]:
    """The ``data`` entry of an export: the checkpoint's, completed (never contradicted) by the given values."""
    stored = dict(info.get("data") or {})
    given = {"image_size": _size_pair(image_size) if image_size is not None else None,
             "resolution_m": float(resolution_m) if resolution_m is not None else None,
             "input_encoding": input_encoding}
    data = {}
    for key, value in given.items():
        have = stored.get(key)
        if key == "image_size" and have is not None:
            have = _size_pair(have)
        if have is not None and value is not None and value != have:
            raise ExportError(
                f"{key}={value!r} contradicts {source}, which was trained with {key}={have!r}: leave {key} out "
                "(the student only works on the windows it was trained on)"
            )
        data[key] = have if have is not None else value
    missing = [k for k in ("image_size", "resolution_m") if data[k] is None]
    if missing:
        raise ExportError(
            f"{source} does not record its training window ({', '.join(missing)} missing: it predates the 'data' "
            "entry or was made by hand). Pass them as the student was trained, e.g. image_size=[64,64] "
            "resolution_m=0.1 for scale=tiny/cpu, image_size=[128,128] resolution_m=0.05 for scale=paper"
        )
    if data["input_encoding"] is None:
        data["input_encoding"] = DEFAULT_INPUT_ENCODING
    if not data["resolution_m"] > 0:
        raise ExportError(f"resolution_m must be a positive number of metres per pixel, got {data['resolution_m']}")
    return data


def _size_pair(size: int | Sequence[int]) -> list[int]:
    if isinstance(size, (int, np.integer)):
        return [int(size), int(size)]
    values = [int(v) for v in size]
    if len(values) != 2 or min(values) < 1:
        raise ExportError(f"image_size must be one positive int or [H, W], got {size!r}")
    return values


# -- export ----------------------------------------------------------------------------------------------------
def export_net(net: nn.Module, out_path: str | Path, fmt: str, image_size: Sequence[int],
               metadata: dict[str, Any], opset: int = DEFAULT_OPSET) -> Path:
    """Write ``net`` (a student U-Net) as ``fmt`` with ``metadata`` embedded; the file appears only when complete."""
    fmt = check_format(fmt)
    h, w = _size_pair(image_size)
    multiple = int(getattr(net, "resolution_multiple", 1))
    if h % multiple or w % multiple:
        raise ExportError(f"image_size {h}x{w} is not a multiple of {multiple}, which this student needs")
    out = Path(out_path).expanduser()
    out.parent.mkdir(parents=True, exist_ok=True)
    net = net.eval()
    example = torch.zeros(1, int(getattr(net, "in_channels", 3)), h, w, device=next(net.parameters()).device)
    text = json.dumps(metadata)
    tmp = out.with_name(f".{out.stem}.{os.getpid()}.tmp{out.suffix}")
    try:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", category=torch.jit.TracerWarning)  # input checks are traced as constants
            warnings.filterwarnings("ignore", category=DeprecationWarning)  # see the module docstring
            warnings.filterwarnings("ignore", category=FutureWarning)
            if fmt == "onnx":
                _export_onnx(net, example, tmp, text, opset)
            else:
                traced = torch.jit.freeze(torch.jit.trace(net, example, check_trace=False))
                torch.jit.save(traced, str(tmp), _extra_files={TORCHSCRIPT_METADATA_FILE: text})
        tmp.replace(out)
    finally:
        tmp.unlink(missing_ok=True)
    return out


def _export_onnx(net: nn.Module, example: torch.Tensor, path: Path, metadata_json: str, opset: int) -> None:
    onnx = _import("onnx")
    torch.onnx.export(
        net, (example,), str(path), dynamo=False, opset_version=opset, do_constant_folding=True,
        input_names=[INPUT_NAME], output_names=[OUTPUT_NAME],
        dynamic_axes={INPUT_NAME: {0: "N"}, OUTPUT_NAME: {0: "N"}},
    )
    model = onnx.load(str(path))
    entry = model.metadata_props.add()
    entry.key, entry.value = METADATA_KEY, metadata_json
    onnx.checker.check_model(model)
    onnx.save(model, str(path))


def check_format(fmt: str) -> str:
    """``fmt`` lower-cased, or an :class:`ExportError` naming the valid formats."""
    value = str(fmt).lower()
    if value not in FORMATS:
        raise ExportError(f"unknown export format {fmt!r}; use format=onnx (onnxruntime) or format=torchscript (LibTorch)")
    return value


def _import(name: str) -> Any:
    try:
        return __import__(name)
    except ImportError:  # pragma: no cover - depends on the installed extras
        raise ImportError(f"ONNX export needs the {name} package: pip install -e '.[onnx]'") from None


# -- reading exports back --------------------------------------------------------------------------------------
def read_metadata(path: str | Path) -> dict[str, Any]:
    """The SPADE metadata of an exported ``.onnx`` or TorchScript file (see the module docstring)."""
    path = Path(path).expanduser()
    if not path.is_file():
        raise FileNotFoundError(f"{path} does not exist; export a student with python -m spade.export ckpt_path=...")
    fix = "export the student with python -m spade.export ckpt_path=<student .ckpt>"
    if zipfile.is_zipfile(path):  # TorchScript archives are zip files with extra files under <archive>/extra/
        with zipfile.ZipFile(path) as archive:
            names = [n for n in archive.namelist() if n.endswith(f"/extra/{TORCHSCRIPT_METADATA_FILE}")]
            if not names:
                raise ExportError(f"{path} is a zip/TorchScript file without SPADE metadata ({TORCHSCRIPT_METADATA_FILE}): {fix}")
            return json.loads(archive.read(names[0]))
    onnx = _import("onnx")
    try:
        model = onnx.load(str(path), load_external_data=False)
    except Exception as err:  # protobuf raises several types on a file that is not ONNX
        raise ExportError(f"{path} is neither an ONNX nor a TorchScript file ({type(err).__name__}): {fix}") from None
    props = {p.key: p.value for p in model.metadata_props}
    if METADATA_KEY not in props:
        raise ExportError(f"{path} carries no '{METADATA_KEY}' metadata, so it is not a SPADE student export: {fix}")
    return json.loads(props[METADATA_KEY])


class ExportedStudent:
    """An exported student ready to run: ``logits = ExportedStudent(path)(state)`` with numpy or torch input."""

    def __init__(self, path: str | Path, threads: int | None = None) -> None:
        self.path = Path(path)
        self.metadata = read_metadata(self.path)
        self.format = "torchscript" if zipfile.is_zipfile(self.path) else "onnx"
        self.runtime = RUNTIMES[self.format]
        if self.format == "onnx":
            ort = _import("onnxruntime")
            options = ort.SessionOptions()
            if threads:
                options.intra_op_num_threads = int(threads)
            self._session = ort.InferenceSession(str(self.path), options, providers=["CPUExecutionProvider"])
        else:
            with warnings.catch_warnings():
                warnings.filterwarnings("ignore", category=DeprecationWarning)
                self._module = torch.jit.load(str(self.path), map_location="cpu")

    def __call__(self, state: np.ndarray | torch.Tensor) -> np.ndarray:
        if isinstance(state, torch.Tensor):
            state = state.detach().cpu().numpy()
        x = np.ascontiguousarray(state, dtype=np.float32)
        if self.format == "onnx":
            return self._session.run([OUTPUT_NAME], {INPUT_NAME: x})[0]
        with torch.inference_mode():
            return self._module(torch.from_numpy(x)).numpy()


def example_states(n: int, image_size: Sequence[int], seed: int = 0) -> torch.Tensor:
    """``n`` states in the network's input encoding: occupancy 0 / 0.5 / 1, one start disc, one goal disc."""
    h, w = _size_pair(image_size)
    rng = np.random.default_rng(seed)
    state = np.zeros((n, 3, h, w), dtype=np.float32)
    state[:, 0] = rng.choice(np.array([0.0, 0.5, 1.0], dtype=np.float32), size=(n, h, w), p=[0.2, 0.6, 0.2])
    rows, cols = np.mgrid[:h, :w]
    radius = max(1.0, min(h, w) / 32)
    for i in range(n):
        for channel in (1, 2):
            r, c = rng.uniform(radius, h - radius), rng.uniform(radius, w - radius)
            state[i, channel] = ((rows - r) ** 2 + (cols - c) ** 2 <= radius**2).astype(np.float32)
    return torch.from_numpy(state)


def max_abs_diff(net: nn.Module, exported: ExportedStudent, image_size: Sequence[int], batch: int = 4,
                 seed: int = 0) -> float:
    """max |logits(export) - logits(PyTorch)| over ``batch`` example states (another batch size than exported)."""
    state = example_states(batch, image_size, seed)
    with torch.inference_mode():
        reference = net.eval()(state).numpy()
    got = exported(state)
    if got.shape != reference.shape:
        raise ExportError(f"{exported.path}: output shape {got.shape} differs from PyTorch's {reference.shape}")
    return float(np.abs(got - reference).max())


def latency_ms(net: nn.Module, exported: ExportedStudent, image_size: Sequence[int], batches: Sequence[int] = (1,),
               runs: int = 20, warmup: int = 3) -> dict[str, float]:
    """Median ms per forward pass, eager PyTorch and the export's runtime, for each batch size."""
    from spade.perf.timing import measure

    out: dict[str, float] = {}
    for b in batches:
        state = example_states(int(b), image_size, seed=1)
        array = state.numpy()
        with torch.inference_mode():
            out[f"eager_b{b}"] = measure(lambda: net(state), runs, warmup).median_ms
        out[f"{exported.runtime}_b{b}"] = measure(lambda: exported(array), runs, warmup).median_ms
    return out


def export_student(
    ckpt_path: str | Path,
    out_path: str | Path | None = None,
    fmt: str = "onnx",
    *,
    image_size: int | Sequence[int] | None = None,
    resolution_m: float | None = None,
    input_encoding: str | None = None,
    opset: int = DEFAULT_OPSET,
    parity_batch: int = 4,
    tolerance: float | None = DEFAULT_TOLERANCE,
    latency_runs: int = 20,
    latency_batches: Sequence[int] = (1,),
    threads: int | None = None,
) -> ExportReport:
    """Export a student checkpoint, check it against PyTorch and time both.

    Args:
        ckpt_path: a StudentModule checkpoint (``checkpoint["spade"]["role"] == "student"``).
        out_path: where to write; default: the checkpoint's path with ``.onnx`` / ``.pt``.
        fmt: ``onnx`` or ``torchscript``.
        image_size, resolution_m, input_encoding: only for checkpoints that do not record their training window.
        parity_batch: example states compared (a batch size other than the exported 1, so the dynamic axis is
            exercised too).
        tolerance: raise when the max |logit difference| exceeds it (None: only report).
        latency_runs, latency_batches: timed forward passes per batch size (0 runs: no timing).
        threads: onnxruntime intra-op threads (None: its default, all cores).
    """
    fmt = check_format(fmt)
    net, info = load_student_checkpoint(ckpt_path)
    data = window_metadata(info, image_size, resolution_m, input_encoding, source=str(ckpt_path))
    metadata = {
        "role": "student",
        "config": dict(info["config"]),
        "data": data,
        "source_checkpoint": str(Path(ckpt_path).expanduser().resolve()),
        "torch_version": torch.__version__,
        "opset": opset if fmt == "onnx" else None,
        "format": fmt,
        "input": {"name": INPUT_NAME, "dtype": "float32", "shape": ["N", int(net.in_channels), *data["image_size"]]},
        "output": {"name": OUTPUT_NAME, "dtype": "float32", "shape": ["N", 1, *data["image_size"]],
                   "meaning": "path logits; sigmoid gives the path probability"},
    }
    if info.get("mlflow_run_id"):
        metadata["mlflow_run_id"] = info["mlflow_run_id"]
    out = Path(out_path) if out_path else Path(ckpt_path).with_suffix(SUFFIXES[fmt])
    export_net(net, out, fmt, data["image_size"], metadata, opset)
    exported = ExportedStudent(out, threads=threads)
    diff = max_abs_diff(net, exported, data["image_size"], parity_batch)
    if tolerance is not None and not diff <= tolerance:
        raise ExportError(
            f"{out} does not reproduce the checkpoint: max |logit difference| {diff:.3g} > tolerance {tolerance:g}. "
            "Try another opset or format=torchscript, and report it"
        )
    latency = latency_ms(net, exported, data["image_size"], latency_batches, latency_runs) if latency_runs > 0 else {}
    return ExportReport(out, fmt, diff, parity_batch, latency, metadata)
