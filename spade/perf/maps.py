"""The map layer: loading and resampling real ROS maps, generating procedural ones, and what they leave a robot
(the ``maps`` section of ``python -m spade.bench``)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
from spade.maps import (
    GENERATORS,
    generate_map,
    largest_free_component,
    load_ros_map,
    max_clear_square_m,
    traversable_mask,
)


def real_map_costs(maps_dir: str | Path, resolution_m: float = 0.05, robot_radius_m: float = 0.22,
                   limit: int | None = None) -> list[dict[str, Any]]:
    """Per ROS map yaml below ``maps_dir`` (sorted; the first ``limit``): size, m/px, occupied / free / unknown
    fractions, ms to load and to resample to ``resolution_m``, and the side of the largest square a robot of
    ``robot_radius_m`` can stand in (metres)."""
    rows = []
    for path in sorted(Path(maps_dir).expanduser().rglob("*.yaml"))[:limit]:
        t0 = time.perf_counter()
        m = load_ros_map(path)
        t1 = time.perf_counter()
        resampled = m.resampled(resolution_m)
        t2 = time.perf_counter()
        rows.append({"map": m.name, "width": m.width, "height": m.height, "resolution_m": m.resolution,
                     **m.fractions(), "load_ms": (t1 - t0) * 1e3, "resample_ms": (t2 - t1) * 1e3,
                     "resample_to_m": resolution_m,
                     "clear_square_m": max_clear_square_m(resampled, robot_radius_m)})
    return rows


def procedural_map_costs(seeds: int, robot_radius_m: float = 0.22) -> list[dict[str, Any]]:
    """Per procedural generator (default size, 0.05 m/px), over seeds ``0 .. seeds - 1``: mean ms to generate, mean
    fractions, and the worst case of the largest clear square (m) and of the share of the traversable cells that
    the largest connected free component reaches."""
    rows = []
    for kind in sorted(GENERATORS):
        times, squares, reach, fractions = [], [], [], []
        for seed in range(seeds):
            t0 = time.perf_counter()
            m = generate_map(kind, seed)
            times.append(time.perf_counter() - t0)
            squares.append(max_clear_square_m(m, robot_radius_m))
            traversable = traversable_mask(m, robot_radius_m)
            reach.append(largest_free_component(m, robot_radius_m).sum() / max(1, traversable.sum()))
            fractions.append([m.fractions()[k] for k in ("occupied", "free", "unknown")])
        mean = np.mean(fractions, axis=0)
        rows.append({"kind": kind, "width": m.width, "height": m.height, "seeds": seeds,
                     "generate_ms": float(np.mean(times)) * 1e3, "occupied": float(mean[0]), "free": float(mean[1]),
                     "unknown": float(mean[2]), "min_clear_square_m": float(min(squares)),
                     "min_reach": float(min(reach))})
    return rows
