"""What one training step costs against what the cores can do: its FLOPs (torch's FLOP counter), a matmul's FLOP
rate to compare its rate with, and where its time goes (torch.profiler's top operators by self CPU time)."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import torch
from torch.utils.flop_counter import FlopCounterMode


def step_gflop(step: Callable[[], Any]) -> float:
    """GFLOP (multiply-add = 2) of one call of ``step`` (forward, backward and optimiser step), counted by
    :class:`torch.utils.flop_counter.FlopCounterMode`: convolutions, matmuls and their gradients; elementwise
    work (normalisation, activations, the optimiser's updates) is not counted, so the rate below is that of the
    counted work, the one a matmul reference measures too."""
    with FlopCounterMode(display=False) as counter:
        step()
    return counter.get_total_flops() / 1e9


def matmul_gflops(n: int = 1024, seconds: float = 0.5, dtype: torch.dtype = torch.float32) -> float:
    """GFLOP/s of a loop of ``n`` x ``n`` matmuls (``dtype``) run for about ``seconds``: what the cores reach on
    the densest kernel torch has, with the threads and the load of this moment."""
    a, b = torch.randn(n, n, dtype=dtype), torch.randn(n, n, dtype=dtype)
    torch.mm(a, b)  # warm-up: allocation, threads
    count, t0 = 0, time.perf_counter()
    while True:
        torch.mm(a, b)
        count += 1
        elapsed = time.perf_counter() - t0
        if elapsed >= seconds:
            return 2.0 * n ** 3 * count / elapsed / 1e9


def top_operators(step: Callable[[], Any], top: int = 10) -> list[dict[str, Any]]:
    """The ``top`` operators of one call of ``step`` by self CPU time (:mod:`torch.profiler`), each with its
    share of the step's total self CPU time and its call count."""
    from torch.profiler import ProfilerActivity, profile

    with profile(activities=[ProfilerActivity.CPU]) as prof:
        step()
    events = [e for e in prof.key_averages() if e.self_cpu_time_total > 0]
    total = sum(e.self_cpu_time_total for e in events) or 1.0
    events.sort(key=lambda e: e.self_cpu_time_total, reverse=True)
    return [{"op": e.key, "self_cpu_ms": e.self_cpu_time_total / 1e3, "share": e.self_cpu_time_total / total,
             "calls": int(e.count)} for e in events[:top]]
