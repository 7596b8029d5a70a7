"""How many intra-op threads a training process uses: the cores it may run on, minus those others keep busy.

On a 2-core machine, two training processes that each keep torch's default two intra-op threads (spinning while
they wait for work: OpenMP's active wait) slow each other far more than two-fold; ``python -m spade.bench
sections=[contention]`` measures it, per thread count and wait policy. The passive wait policy
(``OMP_WAIT_POLICY=PASSIVE``: idle threads sleep instead of spinning) is what ``spade.train`` and
``spade.evaluate`` set (:func:`prefer_passive_wait`, unless the user set it): it must be set before the OpenMP
runtime starts, i.e. before torch is imported, and it keeps the thread count, so reruns stay bit-identical.
:func:`configure_threads` also offers ``threads=N`` and ``threads=auto`` (the cores free when the run starts).
"""

from __future__ import annotations

import os
import time

from spade.utils.errors import ConfigError

__all__ = ["available_cores", "busy_cores", "configure_threads", "prefer_passive_wait", "training_threads"]


def prefer_passive_wait() -> None:
    """``OMP_WAIT_POLICY=PASSIVE`` unless set: idle OpenMP threads yield their core to other processes. Call it
    before ``import torch`` (the runtime reads it once, when it starts)."""
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")


def available_cores() -> int:
    """The cores this process may run on (its CPU affinity, which containers and ``taskset`` restrict)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def _cpu_times() -> tuple[float, float] | None:
    try:
        with open("/proc/stat") as f:
            fields = [float(v) for v in f.readline().split()[1:]]
    except OSError:
        return None
    idle = fields[3] + (fields[4] if len(fields) > 4 else 0.0)  # idle + iowait
    return sum(fields), idle


def busy_cores(window_s: float = 0.3) -> float:
    """Cores kept busy by all processes over a short window (from ``/proc/stat``; the 1-minute load average
    where that is missing)."""
    first = _cpu_times()
    if first is None:
        try:
            return float(os.getloadavg()[0])
        except OSError:
            return 0.0
    time.sleep(window_s)
    second = _cpu_times()
    total, idle = second[0] - first[0], second[1] - first[1]
    cores = os.cpu_count() or 1
    return 0.0 if total <= 0 else cores * (total - idle) / total


def training_threads(cores: int | None = None, busy: float | None = None) -> int:
    """Intra-op threads for a training process: the available cores minus the busy ones (rounded), at least one."""
    cores = available_cores() if cores is None else cores
    busy = busy_cores() if busy is None else busy
    return max(1, min(cores, cores - int(round(busy))))


def configure_threads(threads: int | str | None) -> int:
    """Set torch's intra-op threads: a number, ``auto`` (:func:`training_threads`; ``OMP_NUM_THREADS``, when set,
    wins), or None (torch's default: one per available core). Returns the count in use."""
    import torch

    if threads in (None, "", "default"):
        return torch.get_num_threads()
    if threads == "auto":
        if os.environ.get("OMP_NUM_THREADS"):  # the user (or a launcher) chose: torch already follows it
            return torch.get_num_threads()
        count = training_threads()
    elif isinstance(threads, int) and not isinstance(threads, bool) and threads >= 1:
        count = threads
    elif isinstance(threads, str) and threads.isdigit() and int(threads) >= 1:
        count = int(threads)
    else:
        raise ConfigError(f"threads={threads!r} is not a thread count; set it to auto, a number >= 1, or null "
                         "(torch's default)")
    torch.set_num_threads(count)
    return count
