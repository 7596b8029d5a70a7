"""Small synthetic instances for storage tests (the annotation tool makes the real ones)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from skimage.draw import disk, line

from spade.data import DatasetWriter, resample_polyline


def site_map(root: Path) -> Path:
    """A 12 m x 10 m walled site at 0.1 m/px (a ROS yaml and its image) under ``root``."""
    from spade.maps import OccupancyMap, save_ros_map

    g = np.ones((100, 120), np.uint8)
    g[[0, -1], :] = 2
    g[:, [0, -1]] = 2
    return save_ros_map(OccupancyMap(g, 0.1, origin=(-2.0, -1.0, 0.0), name="site"), root / "site.yaml")


def synthetic_instance(rng: np.random.Generator, size: int = 32, k: int = 16) -> dict:
    """One L-ish instance: free room with a wall, a start and goal disc and the path between them."""
    occ = np.ones((size, size), dtype=np.uint8)
    occ[:, :2] = 0
    occ[0, :] = 2
    occ[size // 2, 4 : size // 3] = 2
    sx, sy = int(rng.integers(4, size // 2)), int(rng.integers(size // 2 + 2, size - 4))
    gx, gy = int(rng.integers(size // 2, size - 4)), int(rng.integers(3, size // 2 - 2))
    corners = np.array([[sx, sy], [sx, gy], [gx, gy]], dtype=np.float64)
    path = np.zeros((size, size), dtype=bool)
    for (x0, y0), (x1, y1) in zip(corners[:-1], corners[1:]):
        rr, cc = line(int(y0), int(x0), int(y1), int(x1))
        path[rr, cc] = True
    start = np.zeros_like(path)
    goal = np.zeros_like(path)
    start[disk((sy, sx), 2, shape=path.shape)] = True
    goal[disk((gy, gx), 2, shape=path.shape)] = True
    return {
        "occupancy": occ,
        "start": start,
        "goal": goal,
        "path": path,
        "waypoints": resample_polyline(corners, k).astype(np.float32),
        "pose": (float(sx) * 0.05, float(sy) * 0.05, float(rng.uniform(-np.pi, np.pi))),
    }


def write_synthetic(root: Path, n: int = 10, size: int = 32, k: int = 16, seed: int = 0) -> list[dict]:
    """Write ``n`` synthetic instances to ``root``; returns them for comparison."""
    rng = np.random.default_rng(seed)
    items = []
    with DatasetWriter(root, image_size=size, resolution=0.05, num_waypoints=k, generator_config={"seed": seed}) as w:
        for i in range(n):
            inst = synthetic_instance(rng, size, k)
            labels = {"shape": "LU"[i % 2], "map_id": f"map{i % 3}", "scenario_id": f"map{i % 3}/s{i // 3}"}
            w.add(**inst, **labels)
            items.append({**inst, **labels})
        w.set_extra("rejections", {"collision": 1})
    return items
