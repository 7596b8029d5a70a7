"""A large dataset read in a fresh process: open (manifest and sha256 of every file), one pass item by item and one
through a DataLoader, and the resident memory that takes (the ``dataset`` section of ``python -m spade.bench``).

Without an existing dataset one is written first from the synthetic recipe (:mod:`spade.metrics.synthetic`: L/U
paths with their start and goal discs, on random occupancy); the reader then runs in a child process of its own, so
that neither the writing nor the bench's other sections count towards its memory.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from spade.data import DatasetWriter
from spade.metrics.synthetic import synthetic_batch
from spade.perf.throughput import dataset_read_throughput
import spade.data


def write_synthetic_dataset(root: str | Path, instances: int, image_size: int, num_waypoints: int = 64,
                            seed: int = 0, chunk: int = 500) -> float:
    """Write ``instances`` synthetic instances (0.05 m/px) to ``root``; returns the seconds it took."""
    rng = np.random.default_rng(seed)
    codes = np.array([0, 1, 2], dtype=np.uint8)  # UNKNOWN / FREE / OCCUPIED
    t0 = time.perf_counter()
    with DatasetWriter(root, image_size=image_size, resolution=0.05, num_waypoints=num_waypoints,
                       generator_config={"bench": "synthetic", "instances": instances, "seed": seed}) as writer:
        for first in range(0, instances, chunk):
            n = min(chunk, instances - first)
            batch = synthetic_batch(n, size=image_size, num_points=num_waypoints, seed=seed + first)
            for j in range(n):
                i = first + j
                occupancy = rng.choice(codes, size=(image_size, image_size), p=[0.2, 0.7, 0.1])
                x, y = batch["waypoints"][j, 0] * 0.05
                writer.add(occupancy, batch["state"][j, 1] > 0.5, batch["state"][j, 2] > 0.5,
                           batch["path"][j, 0] > 0.5, batch["waypoints"][j], "LU"[j % 2], f"m{i % 10}",
                           f"m{i % 10}/{i // 200}", (x, y, 0.0))
    return time.perf_counter() - t0


def _rss_mb(field: str = "VmRSS") -> float:
    """This process's resident memory now (``VmRSS``) or at its peak (``VmHWM``, which unlike ``ru_maxrss`` starts
    afresh at exec, so a child does not inherit its parent's peak), in MiB (Linux)."""
    with open("/proc/self/status") as handle:
        for line in handle:
            if line.startswith(f"{field}:"):
                return int(line.split()[1]) / 1024
    raise OSError(f"no {field} in /proc/self/status")


def read_footprint(root: str | Path) -> dict[str, Any]:
    """:func:`spade.perf.throughput.dataset_read_throughput` of ``root`` with this process's resident memory:
    the baseline after importing torch and :mod:`spade.data` (as any training process does), the peak, and the
    peak minus the baseline.
    Meaningful in a fresh process (what :func:`dataset_read_at_scale` runs it in)."""
    import torch  # noqa: F401  (counted in the baseline, as the reader's own code)

    base = _rss_mb()
    out = dataset_read_throughput(root)
    peak = _rss_mb("VmHWM")
    out.update(disk_mib=sum(p.stat().st_size for p in Path(root).iterdir()) / 2**20, rss_baseline_mb=base,
               rss_peak_mb=peak, rss_dataset_mb=peak - base)
    return out


def dataset_read_at_scale(work: str | Path, instances: int, image_size: int, num_waypoints: int = 64,
                          dataset: str | Path | None = None, seed: int = 0) -> dict[str, Any]:
    """Read ``dataset`` (or ``instances`` synthetic ones written under ``work``) in a fresh Python process."""
    out: dict[str, Any] = {}
    if dataset:
        root = Path(dataset).expanduser()
    else:
        root = Path(work) / "dataset_read"
        if not (root / "manifest.json").is_file():  # a kept work_dir: reuse, do not re-time
            out["write_s"] = write_synthetic_dataset(root, instances, image_size, num_waypoints, seed)
    code = ("import json, sys; from spade.perf.dataset import read_footprint; "
            "print(json.dumps(read_footprint(sys.argv[1])))")
    proc = subprocess.run([sys.executable, "-c", code, str(root)], capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"reading {root} in a child process failed:\n{proc.stderr[-4000:]}")
    out.update(json.loads(proc.stdout.strip().splitlines()[-1]), dataset=str(root))
    return out
