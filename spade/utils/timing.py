"""Wall-clock timing of a callable: warm-up runs, then the median (and min) of timed runs, in milliseconds."""

from __future__ import annotations

import os
import platform
import statistics
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Any


@dataclass(frozen=True)
class Timing:
    """Milliseconds per call over ``runs`` timed calls (after ``warmup`` untimed ones)."""

    median_ms: float
    min_ms: float
    runs: int

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def measure(fn: Callable[[], Any], runs: int = 10, warmup: int = 2, min_seconds: float = 0.0) -> Timing:
    """Time ``fn()``: ``warmup`` untimed calls, then at least ``runs`` timed calls (more while the timed total is
    under ``min_seconds``). The median is what to report; the min shows the machine's best case when it is shared.
    """
    if runs < 1:
        raise ValueError(f"runs must be >= 1, got {runs}")
    for _ in range(max(0, warmup)):
        fn()
    times: list[float] = []
    while len(times) < runs or sum(times) < min_seconds:
        t0 = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t0) * 1000.0)
    return Timing(median_ms=statistics.median(times), min_ms=min(times), runs=len(times))


def clocked(spent: dict[str, float], name: str, fn: Callable[..., Any]) -> Callable[..., Any]:
    """``fn`` that also adds its wall time (seconds) to ``spent[name]`` at every call: a part of a larger run timed
    where it runs (wrap a bound method and assign it to the instance)."""
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        start = time.perf_counter()
        try:
            return fn(*args, **kwargs)
        finally:
            spent[name] = spent.get(name, 0.0) + time.perf_counter() - start
    return wrapper


def machine_info() -> dict[str, Any]:
    """What a timing depends on: CPU model and count, load at the start, torch and its thread count."""
    import torch

    info: dict[str, Any] = {
        "cpu": cpu_model(),
        "cpu_count": os.cpu_count(),
        "torch": torch.__version__,
        "torch_threads": torch.get_num_threads(),
        "cuda": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None,
        "python": platform.python_version(),
    }
    try:
        info["load_average_1m"] = round(os.getloadavg()[0], 2)
    except OSError:  # pragma: no cover - platforms without getloadavg
        info["load_average_1m"] = None
    return info


def cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo``; ``platform.processor()`` elsewhere)."""
    try:
        with open("/proc/cpuinfo") as handle:
            for line in handle:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:  # pragma: no cover - non-Linux
        pass
    return platform.processor() or "unknown"


def step_time(module: Any, batch: dict[str, Any], runs: int = 3, warmup: int = 1) -> dict[str, float]:
    """Median (and min) ms of one optimisation step of a module with ``losses(batch)["loss"]`` (a SPADE
    student or expert) on ``batch``: loss, backward, AdamW step, no Lightning bookkeeping."""
    import torch

    optimizer = torch.optim.AdamW([p for p in module.parameters() if p.requires_grad], lr=1e-3)

    def step() -> None:
        optimizer.zero_grad(set_to_none=True)
        module.losses(batch)["loss"].backward()
        optimizer.step()

    timing = measure(step, runs, warmup)
    return {"step_ms": timing.median_ms, "step_min_ms": timing.min_ms, "runs": timing.runs}
