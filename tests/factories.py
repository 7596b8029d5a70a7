"""Small synthetic test material: instances for storage tests (the annotation tool makes the real ones), a walled
site map, and a stand-in network whose answer is known."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from skimage.draw import disk, line

from spade.data import DatasetWriter, resample_polyline


def site_map(root: Path, block: bool = False) -> Path:
    """A 12 m x 10 m walled site at 0.1 m/px, origin (-2, -1) (a ROS yaml and its image) under ``root``; with
    ``block``, a 1 m obstacle centred on (4, 4) m."""
    from spade.maps import OccupancyMap, save_ros_map

    g = np.ones((100, 120), np.uint8)
    g[[0, -1], :] = 2
    g[:, [0, -1]] = 2
    if block:
        g[45:55, 55:65] = 2
    return save_ros_map(OccupancyMap(g, 0.1, origin=(-2.0, -1.0, 0.0), name="site"), root / "site.yaml")


class LineOracle:
    """A stand-in network that 'predicts' the straight segment between the start and goal discs of its input."""

    info: dict = {}

    def logits(self, states: np.ndarray) -> np.ndarray:
        from scipy import ndimage

        out = np.full((len(states), 1, *states.shape[2:]), -10.0, dtype=np.float32)
        for i, state in enumerate(states):
            (r0, c0), (r1, c1) = (np.rint(ndimage.center_of_mass(state[k])).astype(int) for k in (1, 2))
            rr, cc = line(r0, c0, r1, c1)
            out[i, 0, rr, cc] = 10.0
        return out


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


def hand_made_checkpoint(path: Path, role: str = "student", data: dict | None = None, size: str = "small") -> Path:
    """A checkpoint of the layout a fit writes (state_dict with ``net.`` keys, ``spade`` entry), without Lightning;
    untrained weights, BatchNorm statistics moved off their defaults so that eval mode is exercised."""
    import torch

    from spade.models.builders import build_model

    torch.manual_seed(0)
    net = build_model("student", size)
    with torch.no_grad():
        for module in net.modules():
            if isinstance(module, torch.nn.BatchNorm2d):
                module.running_mean.uniform_(-0.5, 0.5)
                module.running_var.uniform_(0.5, 2.0)
    info = {"role": role, "config": dict(net.config)}
    if data is not None:
        info["data"] = data
    torch.save({"state_dict": {f"net.{k}": v for k, v in net.state_dict().items()}, "spade": info}, path)
    return path
