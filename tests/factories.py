"""Small synthetic test material: instances for storage tests (the annotation tool makes the real ones), a walled
site map, a stand-in network whose answer is known, untrained checkpoints, planner poses and closed-loop scenarios,
the sketch server's settings and the script prefix that hides torch from a subprocess."""

from __future__ import annotations

import math
import textwrap
from pathlib import Path

import numpy as np
from scipy import ndimage
from skimage.draw import disk, line

from spade.closedloop.scenario_loading import Scenario
from spade.data import DatasetWriter, resample_polyline
from spade.maps import FREE, OccupancyMap
from spade.maps.costmap import build_costmap
from spade.maps.frame import RobotFrame
import json
import pytest


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


# A student's window at scale=tiny and the data record of a checkpoint trained on it.
SIZE, RES = 64, 0.1  # scale=tiny's window
FRAME = RobotFrame.for_size(SIZE)  # robot at (32, 48), heading up
ROBOT_DATA = {"image_size": [SIZE, SIZE], "resolution_m": RES, "frame": FRAME.to_json()}


def fresh_checkpoint(path: Path, data: dict | None = None) -> Path:
    """A student checkpoint as spade.train writes it (untrained weights), without training."""
    import torch

    from spade.models.builders import build_model

    torch.manual_seed(0)
    net = build_model("student", "small")
    info = {"role": "student", "config": dict(net.config)}
    if data is not None:
        info["data"] = data
    torch.save({"spade": info, "state_dict": {f"net.{k}": v for k, v in net.state_dict().items()}}, path)
    return path


def open_segment(m: OccupancyMap, length_m: float, seed: int = 0, clearance_m: float = 0.3
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Start and goal (metres) ``length_m`` apart, the segment between them on cells with ``clearance_m``."""
    coarse = m.resampled(RES)
    clear = ndimage.distance_transform_edt(coarse.grid == FREE) * RES
    rows, cols = np.nonzero(clear >= clearance_m)
    rng = np.random.default_rng(seed)
    for i in rng.permutation(len(rows)):
        angle = rng.uniform(0, 2 * np.pi)
        a = coarse.pixel_to_world(np.array([cols[i], rows[i]], dtype=float))
        b = a + length_m * np.array([np.cos(angle), np.sin(angle)])
        px = np.rint(coarse.world_to_pixel(np.linspace(a, b, 50))).astype(int)
        inside = (px >= 0).all() and (px[:, 0] < coarse.width).all() and (px[:, 1] < coarse.height).all()
        if inside and (clear[px[:, 1], px[:, 0]] >= clearance_m).all():
            return a, b
    raise AssertionError("no open segment found")


def facing(a: np.ndarray, b: np.ndarray, turn: float = 0.0) -> np.ndarray:
    """The pose (x, y, yaw) of a robot at ``a`` facing ``b`` (turned by ``turn`` radians, counter-clockwise)."""
    d = b - a
    return np.array([a[0], a[1], math.atan2(d[1], d[0]) + turn])


#: The footprint of the closed-loop scenarios.
ROBOT = {"radius_m": 0.105, "inflation_radius_m": 0.55, "cost_scaling_factor": 3.0}


def arc_l(start: np.ndarray, leg: float, radius: float, tail: float, left: bool = True, n: int = 64) -> np.ndarray:
    """An L along +x from ``start``: a leg, a quarter circle of ``radius`` (to the left or right), a tail."""
    sign = 1.0 if left else -1.0
    phi = np.linspace(0, math.pi / 2, 40)
    leg_pts = np.stack([np.linspace(0, leg, 20), np.zeros(20)], axis=1)
    arc = np.stack([leg + radius * np.sin(phi), sign * radius * (1 - np.cos(phi))], axis=1)
    tail_pts = arc[-1] + np.stack([np.zeros(20), sign * np.linspace(0, tail, 20)], axis=1)
    return resample_polyline(np.vstack([leg_pts, arc[1:], tail_pts[1:]]) + start, n)


def scenario(m: OccupancyMap, demo: np.ndarray, alternatives: np.ndarray | None = None, sid: str = "room/L000"
             ) -> Scenario:
    yaw = math.atan2(demo[1, 1] - demo[0, 1], demo[1, 0] - demo[0, 0])
    return Scenario(sid, m.name, "L", m, build_costmap(m.grid, m.resolution, ROBOT, 4.0),
                    np.array([demo[0, 0], demo[0, 1], yaw]), demo[-1].copy(), demo,
                    np.zeros((0, len(demo), 2)) if alternatives is None else alternatives, 0.6)


#: How far the ONNX and TorchScript runtimes may stray from torch on the same input.
PARITY_BOUND = 1e-4  # float32 reorderings in the runtimes stay near 1e-5 for logits of order 1-10


# The sketch server's tiny annotation settings, an L sketch on the site map, and the host it answers to.
TINY = ["window.size_px=64", "window.resolution_m=0.1", "instances.spacing_m=0.15", "preview.count=4"]
L_WAYPOINTS = [[0.0, 1.0], [1.5, 1.0], [2.5, 1.0], [3.1, 1.3], [3.4, 2.0], [3.4, 3.0]]
LOCAL = "http://127.0.0.1:8765"  # the server answers only to its own host names (spade.sketching.app)


#: The packages the deploy install goes without.
HIDDEN = ("torch", "torchmetrics", "torchvision", "diffusers", "lightning", "pytorch_lightning", "onnx")
# Run before anything else in the subprocess: the hidden packages raise ModuleNotFoundError, as when not installed.
HIDE = textwrap.dedent(f"""
    import sys
    HIDDEN = {HIDDEN!r}

    class NotInstalled:
        def find_spec(self, name, path=None, target=None):
            if name.split(".")[0] in HIDDEN:
                raise ModuleNotFoundError(f"No module named {{name!r}}", name=name)
            return None

    sys.meta_path.insert(0, NotInstalled())
""")


def student_checkpoint(path: Path, role: str = "student", size: int = 64) -> Path:
    """A checkpoint as spade.train writes it (an untrained small student), without training."""
    import torch

    from spade.maps.frame import RobotFrame
    from spade.models.builders import build_model

    net = build_model("student", "small")
    info = {"role": role, "config": dict(net.config),
            "data": {"image_size": [size, size], "resolution_m": 0.1, "frame": RobotFrame.for_size(size).to_json()}}
    path.parent.mkdir(parents=True, exist_ok=True)
    torch.save({"spade": info, "state_dict": {f"net.{k}": v for k, v in net.state_dict().items()}}, path)
    return path


def checkpoint(path: Path, role: str = "student", size: int = 32, resolution: float = 0.05) -> Path:
    """A SPADE checkpoint of ``role`` whose window geometry is ``write_synthetic``'s (32 px at 0.05 m/px)."""
    import torch

    from spade.maps.frame import RobotFrame

    student_checkpoint(path, role, size)
    data = torch.load(path, weights_only=False)
    data["spade"]["data"] = {"image_size": [size, size], "resolution_m": resolution,
                             "frame": RobotFrame.for_size(size).to_json()}
    if role == "expert":
        data["spade"]["config"] = {**data["spade"]["config"], "role": "cond_expert"}
    else:  # loadable by Lightning as well (spade.evaluate)
        import lightning

        data.update({"pytorch-lightning_version": lightning.__version__, "hyper_parameters": {"size": "small"}})
    torch.save(data, path)
    return path


def spade_onnx(path: Path, metadata: dict | None = None, channels: int = 3) -> Path:
    """An ONNX Identity graph carrying ``metadata`` as its ``spade`` entry: a file SPADE's output check takes for
    an export of its own (its ``spade`` entry has a role), and, with a real export's metadata copied in, the
    forged model. ``state`` (N, channels, 64, 64) -> ``logits`` (the same)."""
    onnx = pytest.importorskip("onnx")
    from onnx import TensorProto, helper

    dims = ["N", channels, 64, 64]
    graph = helper.make_graph([helper.make_node("Identity", ["state"], ["logits"])], "forged",
                              [helper.make_tensor_value_info("state", TensorProto.FLOAT, dims)],
                              [helper.make_tensor_value_info("logits", TensorProto.FLOAT, dims)])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    entry = model.metadata_props.add()
    entry.key, entry.value = "spade", json.dumps(metadata or {"role": "student"})
    onnx.save(model, str(path))
    return path


def export_metadata(path: Path) -> dict:
    from spade.models.modelfile import read_metadata

    return read_metadata(path)


def one_node_graph(path: Path, metadata: dict, node: object, initializer: list) -> Path:
    """A forged model of the right shapes, (N, 3, 64, 64) -> (N, 1, 64, 64), of one ``node`` (reading ``state``,
    writing ``logits``) and its ``initializer`` tensors, with ``metadata`` as its ``spade`` entry."""
    onnx = pytest.importorskip("onnx")
    from onnx import TensorProto, helper

    graph = helper.make_graph([node], "forged",
                              [helper.make_tensor_value_info("state", TensorProto.FLOAT, ["N", 3, 64, 64])],
                              [helper.make_tensor_value_info("logits", TensorProto.FLOAT, ["N", 1, 64, 64])],
                              initializer=initializer)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    entry = model.metadata_props.add()
    entry.key, entry.value = "spade", json.dumps(metadata)
    onnx.save(model, str(path))
    return path


def edited_copy(src: Path, dst: Path, *, metadata: dict | None = None, weight_delta: float = 0.0) -> Path:
    """``src`` with its ``spade`` metadata replaced and/or one weight changed by ``weight_delta``."""
    onnx = pytest.importorskip("onnx")
    from onnx import numpy_helper

    model = onnx.load(str(src))
    if metadata is not None:
        next(e for e in model.metadata_props if e.key == "spade").value = json.dumps(metadata)
    if weight_delta:
        init = max(model.graph.initializer, key=lambda t: len(t.raw_data))
        values = numpy_helper.to_array(init).copy()
        values.flat[0] += weight_delta
        init.CopyFrom(numpy_helper.from_array(values, init.name))
    onnx.save(model, str(dst))
    return dst
