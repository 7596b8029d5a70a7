"""Export a trained student to ONNX or TorchScript with what a deployment needs to feed it, checked against PyTorch.

The exported model maps ``state`` float32 (N, 3, H, W) (occupancy code * 0.5, start disc, goal disc; N dynamic)
to ``logits`` float32 (N, 1, H, W), before the sigmoid. It carries the checkpoint's ``spade`` entry (role,
network config, the training windows with their robot frame) plus the export's own fields, as JSON
(:func:`spade.models.modelfile.export_metadata`): the ONNX ``metadata_props`` entry ``spade``, or the TorchScript
extra file ``spade.json``. :func:`spade.models.modelfile.read_metadata` reads either back and
:func:`spade.models.modelfile.open_model` runs either (and checkpoints). An ONNX export's metadata also records a
digest of its weights, its output on a fixed probe input and a digest of every metadata field a planner acts on
(``integrity``, :mod:`spade.models.onnx_check`), which every reader checks, so that a graph carrying a copy of
another export's metadata, or an edited field (the resolution, the footprint), is refused. A TorchScript export
carries the same record (its weight digest taken over the archive's code and tensors).

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
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from spade.models.modelfile import (
    ENTRY_KEY,
    INPUT_NAME,
    OUTPUT_NAME,
    TORCHSCRIPT_METADATA_FILE,
    ModelFileError,
    ModelRunner,
    export_metadata,
    load_network,
    open_model,
    read_metadata,
)
from spade.models.onnx_check import (
    INTEGRITY_KEY,
    PROBE_SEED,
    archive_sha256,
    integrity_record,
    probe_record,
    probe_state,
)
from spade.utils.timing import measure

FORMATS = ("onnx", "torchscript")
SUFFIXES = {"onnx": ".onnx", "torchscript": ".pt"}
DEFAULT_OPSET = 17
DEFAULT_TOLERANCE = 1e-3
"""Largest max |logit difference| accepted between the export and PyTorch (float32 reorderings give ~1e-6)."""

ExportError = ModelFileError
"""A checkpoint, option or file that cannot be exported or read; the message names the fix."""
__all__ = ["ExportError", "ExportReport", "example_states", "export_net", "export_student", "read_metadata"]


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
            f"window: {data.get('image_size')} px at {data.get('resolution_m')} m/px, robot frame "
            f"{(data.get('frame') or {}).get('robot_px')} heading up; input: {data.get('input_encoding')}",
            f"parity: max |logit difference| vs PyTorch = {self.max_abs_diff:.3g} over a batch of {self.parity_batch}",
        ]
        record = self.metadata.get(INTEGRITY_KEY) or {}
        if record:
            lines.append(f"recorded for the deploy-time check: weights sha256 {record['weights_sha256'][:12]}..., "
                         f"parity probe (seed {record['probe']['seed']})")
        lines += [f"latency {k}: {v:.2f} ms" for k, v in self.latency_ms.items()]
        return "\n".join(lines)


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
    metadata = json.loads(json.dumps(metadata))  # as a reader parses it: the field digests are of these values
    tmp = out.with_name(f".{out.stem}.{os.getpid()}.tmp{out.suffix}")
    try:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", category=torch.jit.TracerWarning)  # input checks are traced as constants
            warnings.filterwarnings("ignore", category=DeprecationWarning)  # see the module docstring
            warnings.filterwarnings("ignore", category=FutureWarning)
            if fmt == "onnx":
                _export_onnx(net, example, tmp, metadata, opset)
            else:
                _export_torchscript(net, example, tmp, metadata)
        tmp.replace(out)
    finally:
        tmp.unlink(missing_ok=True)
    return out


def _export_onnx(net: nn.Module, example: torch.Tensor, path: Path, metadata: dict[str, Any], opset: int) -> None:
    """Write the ONNX graph with ``metadata`` plus its ``integrity`` record (:mod:`spade.models.onnx_check`): the
    digest of the weights as this file serializes them, and the network's output on the parity probe."""
    onnx = _import("onnx")
    torch.onnx.export(
        net, (example,), str(path), dynamo=False, opset_version=opset, do_constant_folding=True,
        input_names=[INPUT_NAME], output_names=[OUTPUT_NAME],
        dynamic_axes={INPUT_NAME: {0: "N"}, OUTPUT_NAME: {0: "N"}},
    )
    model = onnx.load(str(path))
    # The digest of the bytes onnx.save writes below (adding metadata_props leaves the graph's serialization as is)
    record = integrity_record(model.SerializeToString(), _probe(net, tuple(example.shape)), metadata)
    entry = model.metadata_props.add()
    entry.key, entry.value = ENTRY_KEY, json.dumps({**metadata, INTEGRITY_KEY: record})
    onnx.checker.check_model(model)
    onnx.save(model, str(path))


def _export_torchscript(net: nn.Module, example: torch.Tensor, path: Path, metadata: dict[str, Any]) -> None:
    """Write the traced, frozen module with ``metadata`` plus its ``integrity`` record in ``spade.json``. The
    archive's digest (:func:`~spade.models.onnx_check.archive_sha256`) leaves the extra files out, so it is taken
    from a first save and checked on the second, the one carrying the record."""
    traced = torch.jit.freeze(torch.jit.trace(net, example, check_trace=False))
    torch.jit.save(traced, str(path), _extra_files={TORCHSCRIPT_METADATA_FILE: json.dumps(metadata)})
    record = integrity_record(archive_sha256(path), _probe(net, tuple(example.shape)), metadata)
    torch.jit.save(traced, str(path), _extra_files={TORCHSCRIPT_METADATA_FILE: json.dumps({**metadata,
                                                                                           INTEGRITY_KEY: record})})
    if archive_sha256(path) != record["weights_sha256"]:  # pragma: no cover - torch's serialization changed
        raise ExportError(f"{path}: torch.jit.save wrote another archive the second time; export format=onnx")


def _probe(net: nn.Module, shape: Sequence[int]) -> dict[str, Any]:
    """The ``probe`` record: ``net``'s logits on the fixed probe input, batch 1 of ``shape``'s (C, H, W)."""
    state = probe_state((1, *shape[1:]), PROBE_SEED)
    device = next(net.parameters()).device
    with torch.inference_mode():
        out = net.eval()(torch.from_numpy(state).to(device)).float().cpu().numpy()
    return probe_record(state.shape, out, PROBE_SEED)


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


# -- checks ----------------------------------------------------------------------------------------------------
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


def max_abs_diff(net: nn.Module, exported: ModelRunner, image_size: Sequence[int], batch: int = 4,
                 seed: int = 0) -> float:
    """max |logits(export) - logits(PyTorch)| over ``batch`` example states (another batch size than exported)."""
    state = example_states(batch, image_size, seed)
    with torch.inference_mode():
        reference = net.eval()(state).numpy()
    got = exported(state)
    if got.shape != reference.shape:
        raise ExportError(f"{exported.path}: output shape {got.shape} differs from PyTorch's {reference.shape}")
    return float(np.abs(got - reference).max())


def latency_ms(net: nn.Module, exported: ModelRunner, image_size: Sequence[int], batches: Sequence[int] = (1,),
               runs: int = 20, warmup: int = 3) -> dict[str, float]:
    """Median ms per forward pass, eager PyTorch and the export's runtime, for each batch size."""
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
    opset: int = DEFAULT_OPSET,
    parity_batch: int = 4,
    tolerance: float | None = DEFAULT_TOLERANCE,
    latency_runs: int = 20,
    latency_batches: Sequence[int] = (1,),
    threads: int | None = None,
) -> ExportReport:
    """Export a student checkpoint, check it against PyTorch and time both.

    Args:
        ckpt_path: a StudentModule checkpoint trained on robot-frame windows (older, axis-aligned students are
            refused: the planner could not place their windows).
        out_path: where to write; default: the checkpoint's path with ``.onnx`` / ``.pt``.
        fmt: ``onnx`` or ``torchscript``.
        parity_batch: example states compared (a batch size other than the exported 1, so the dynamic axis is
            exercised too).
        tolerance: raise when the max |logit difference| exceeds it (None: only report).
        latency_runs, latency_batches: timed forward passes per batch size (0 runs: no timing).
        threads: onnxruntime intra-op threads (None: its default, all cores).
    """
    fmt = check_format(fmt)
    net, info = load_network(ckpt_path, role="student")
    metadata = export_metadata(info, fmt, source=ckpt_path, opset=opset, in_channels=int(net.in_channels))
    image_size = metadata["data"]["image_size"]
    out = Path(out_path) if out_path else Path(ckpt_path).with_suffix(SUFFIXES[fmt])
    if out.expanduser().resolve() == Path(ckpt_path).expanduser().resolve():  # never the user's checkpoint
        raise ExportError(f"the export would overwrite the checkpoint {ckpt_path} itself; pass another out_path "
                          f"(e.g. {Path(ckpt_path).with_name(Path(ckpt_path).stem + '.' + fmt + SUFFIXES[fmt])})")
    export_net(net, out, fmt, image_size, metadata, opset)
    exported = open_model(out, threads=threads)
    diff = max_abs_diff(net, exported, image_size, parity_batch)
    if tolerance is not None and not diff <= tolerance:
        raise ExportError(
            f"{out} does not reproduce the checkpoint: max |logit difference| {diff:.3g} > tolerance {tolerance:g}. "
            "Try another opset or format=torchscript, and report it"
        )
    latency = latency_ms(net, exported, image_size, latency_batches, latency_runs) if latency_runs > 0 else {}
    return ExportReport(out, fmt, diff, parity_batch, latency, dict(exported.info))  # as the file carries it
