"""Student latency per size and batch size: eager PyTorch and ONNX Runtime, with the work (GFLOP) it implies."""

from __future__ import annotations

import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch
from torch import nn
from torch.utils.flop_counter import FlopCounterMode

from spade.models.builders import build_model, count_parameters
from spade.utils.timing import measure
from spade.deploy.export import example_states, export_net
from spade.models.modelfile import open_model


def forward_gflop(net: nn.Module, *inputs: torch.Tensor) -> float:
    """Floating-point operations (GFLOP, multiply-add = 2) of one forward pass on ``inputs``."""
    with torch.no_grad(), FlopCounterMode(display=False) as counter:
        net(*inputs)
    return counter.get_total_flops() / 1e9


def student_latency(sizes: Sequence[str], image_size: int, batches: Sequence[int] = (1, 32), runs: int = 10,
                    warmup: int = 2, onnx: bool = True, threads: int | None = None,
                    workdir: str | Path | None = None) -> list[dict[str, Any]]:
    """Median ms per forward pass of each student preset (random weights: the cost does not depend on them).

    One row per size: parameters, GFLOP at batch 1, then ``eager_b<N>_ms`` (``torch.inference_mode``) and, with
    ``onnx``, ``onnxruntime_b<N>_ms`` for the model exported by :func:`spade.deploy.export.export_net`. The
    batch-1 runs are timed ``runs`` times, larger batches ``max(3, runs // 3)`` times.
    """
    rows = []
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        for size in sizes:
            net = build_model("student", size).eval()
            row: dict[str, Any] = {"size": size, "image_size": image_size, "params": count_parameters(net)}
            row["gflop_b1"] = forward_gflop(net, torch.zeros(1, net.in_channels, image_size, image_size))
            exported = None
            if onnx:
                path = export_net(net, Path(tmp) / f"{size}.onnx", "onnx", (image_size, image_size),
                                  {"role": "student", "config": net.config, "data": None})
                exported = open_model(path, threads=threads)
            for b in batches:
                n = runs if b == 1 else max(3, runs // 3)
                state = example_states(int(b), (image_size, image_size), seed=b)
                with torch.inference_mode():
                    timing = measure(lambda: net(state), n, warmup)
                row[f"eager_b{b}_ms"] = timing.median_ms
                row[f"eager_b{b}_min_ms"] = timing.min_ms
                if exported is not None:
                    array = state.numpy()
                    timing = measure(lambda: exported(array), n, warmup)
                    row[f"onnxruntime_b{b}_ms"] = timing.median_ms
                    row[f"onnxruntime_b{b}_min_ms"] = timing.min_ms
            rows.append(row)
    return rows
