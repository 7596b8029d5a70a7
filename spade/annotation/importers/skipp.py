"""Importer for SKIPP's published dataset layout (github.com/charbel-a-hC/SKIPP, HF charbel-a-h/SKIPP-Expert-Data).

Layout, as SKIPP's loader (``dataset/ExpertFlatSimData.py``) reads it: under a task folder (``L_Shape`` or
``U_Shape``), one folder per sequence holding ``{i}_egm.jpg`` and ``{i}_path.png`` for i = 1..N (256 x 256) and
``egm_goal_poses.npy`` with one row per state; the loader marks the goal at ``[row, col] = poses[i-1, :2]``.
The EGM is grey-level: black unknown, grey free, white obstacle, which the loader separates at 60 and 140
(JPEG noise in between); the path image is binary at 128. SKIPP's metric scale is 0.01 m/px.

SKIPP's loader puts the start at a fixed spot; here the start is the end of the path curve farther from the
goal along the curve, so that the stored polyline runs from the robot to the goal as SPADE's format requires. 256 px images
are reduced to ``window.size_px`` (occupancy by block maximum, so an obstacle never disappears), then turned into
SPADE's robot frame (spade.maps.frame: robot at its fixed pixel, heading along the path up the image; cells
that fall outside SKIPP's image are unknown), and the path is re-drawn from its ordered polyline, which keeps it
one connected curve. The recorded pose is in SKIPP's image frame (metres from its top-left corner, y up).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable, Iterator, Mapping

import numpy as np
from PIL import Image
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra
from skimage.measure import block_reduce
from skimage.morphology import skeletonize

from spade.annotation.pipeline import RunStats
from spade.annotation.scenarios import ScenarioResult
from spade.annotation.templates import check_shape
from spade.data.rasterize import Instance, robot_instance
from spade.maps.frame import RobotFrame, yaw_from_heading
from spade.utils.errors import UserError

SKIPP_SIZE = 256
UNKNOWN_MAX, FREE_MAX = 60, 140  # SKIPP's threshold_obs


class SkippImportError(UserError, ValueError):
    """The folder does not follow SKIPP's layout; the message says what is missing."""


def egm_codes(grey: np.ndarray) -> np.ndarray:
    """EGM grey levels -> occupancy codes (UNKNOWN 0 / FREE 1 / OCCUPIED 2), with SKIPP's thresholds."""
    codes = np.ones(grey.shape, dtype=np.uint8)
    codes[grey <= UNKNOWN_MAX] = 0
    codes[grey >= FREE_MAX] = 2
    return codes


def order_path(mask: np.ndarray, goal_rc: np.ndarray) -> np.ndarray | None:
    """Ordered (x, y) pixels of the path curve in ``mask``, from its far end (geodesically farthest from the
    pixel nearest the goal; for a U-turn the start may be close to the goal in a straight line) to the pixel
    nearest the goal, along the shortest 8-connected route over the skeleton; None if the mask is empty."""
    skel = skeletonize(mask)
    rc = np.argwhere(skel)
    if len(rc) == 0:
        return None
    index = -np.ones(mask.shape, dtype=np.int64)
    index[rc[:, 0], rc[:, 1]] = np.arange(len(rc))
    rows, cols, weights = [], [], []
    for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1)):
        r2, c2 = rc[:, 0] + dr, rc[:, 1] + dc
        ok = (r2 >= 0) & (r2 < mask.shape[0]) & (c2 >= 0) & (c2 < mask.shape[1])
        j = np.full(len(rc), -1)
        j[ok] = index[r2[ok], c2[ok]]
        ok &= j >= 0
        rows.append(np.flatnonzero(ok))
        cols.append(j[ok])
        weights.append(np.full(ok.sum(), np.hypot(dr, dc)))
    graph = coo_matrix((np.concatenate(weights), (np.concatenate(rows), np.concatenate(cols))),
                       shape=(len(rc), len(rc))).tocsr()
    end = int(np.argmin(((rc - goal_rc) ** 2).sum(1)))
    dist, pred = dijkstra(graph, directed=False, indices=end, return_predecessors=True)
    start = int(np.argmax(np.where(np.isfinite(dist), dist, -1.0)))  # far end of the curve, along the curve
    chain = [start]
    while chain[-1] != end:
        chain.append(int(pred[chain[-1]]))
    return rc[chain][:, ::-1].astype(np.float64)


def sequences(root: Path) -> list[Path]:
    found = sorted({p.parent for p in root.rglob("egm_goal_poses.npy")})
    if not found:
        raise SkippImportError(f"{root} holds no SKIPP sequence (a folder with egm_goal_poses.npy, {{i}}_egm.jpg and "
                               f"{{i}}_path.png); point skipp.root at a task folder such as .../train/U_Shape")
    return found


def skipp_instances(cfg: Mapping[str, Any], stats: RunStats,
                    progress: Callable[[int], None] = lambda n: None) -> Iterator[tuple[Instance, str, str, str]]:
    """Instances of every sequence under ``skipp.root``."""
    root = Path(cfg["skipp"]["root"]).expanduser()
    shape = check_shape(str(cfg["shape"]))
    size = int(cfg["window"]["size_px"])
    if SKIPP_SIZE % size:
        raise SkippImportError(f"window.size_px={size} must divide SKIPP's {SKIPP_SIZE} px (e.g. 128 or 64)")
    factor = SKIPP_SIZE // size
    res = float(cfg["skipp"]["resolution_m"]) * factor
    disc = float(cfg["instances"]["disc_radius_m"]) / res
    order = str(cfg["skipp"]["goal_order"])
    if order not in ("row_col", "xy"):
        raise SkippImportError(f"skipp.goal_order={order!r}: use row_col (SKIPP's loader) or xy")
    k_wp = int(cfg["num_waypoints"])
    for seq in sequences(root):
        poses = np.load(seq / "egm_goal_poses.npy")
        n = len(list(seq.glob("*_egm.jpg")))
        if poses.ndim != 2 or poses.shape[1] < 2 or len(poses) < n:
            raise SkippImportError(f"{seq}: egm_goal_poses.npy has shape {poses.shape}, expected ({n}, >=2) for "
                                   f"{n} *_egm.jpg files")
        rel = seq.relative_to(root).as_posix() if seq != root else seq.name
        result = ScenarioResult(f"skipp/{rel}", "skipp", shape, 0)
        made = 0
        for i in range(1, n + 1):
            egm_file, path_file = seq / f"{i}_egm.jpg", seq / f"{i}_path.png"
            if not egm_file.is_file() or not path_file.is_file():
                raise SkippImportError(f"{seq}: missing {egm_file.name} or {path_file.name} (files run 1..{n})")
            grey = np.asarray(Image.open(egm_file).convert("L"))
            path_mask = np.asarray(Image.open(path_file).convert("L")) >= 128
            if grey.shape != (SKIPP_SIZE, SKIPP_SIZE) or path_mask.shape != grey.shape:
                raise SkippImportError(f"{egm_file}: images must be {SKIPP_SIZE} x {SKIPP_SIZE}, got {grey.shape}")
            goal = poses[i - 1, :2].astype(np.float64)
            goal_rc = goal if order == "row_col" else goal[::-1]
            ordered = order_path(path_mask, goal_rc)
            if ordered is None or len(ordered) < 2:
                result.rejections["empty_path"] += 1
                continue
            goal_xy = goal_rc[::-1]
            if np.linalg.norm(ordered[-1] - goal_xy) > 1.5:
                ordered = np.concatenate([ordered, goal_xy[None]])
            local = (ordered + 0.5) / factor - 0.5
            occupancy = block_reduce(egm_codes(grey), (factor, factor), np.max).astype(np.uint8)
            inst = robot_instance(occupancy, local, RobotFrame.for_size(size), 0.0, disc, k_wp,
                                  to_world=lambda x, y, h: ((x + 0.5) * res, -(y + 0.5) * res, yaw_from_heading(h)))
            if inst is None:
                result.rejections["path_outside_window"] += 1
                continue
            if (inst.occupancy[inst.path] != 1).any():
                result.rejections["path_non_free"] += 1
                continue
            made += 1
            yield inst, shape, "skipp", result.scenario_id
        stats.add(result)
        stats.scenarios.append({"scenario_id": result.scenario_id, "map_id": "skipp", "shape": shape, "instances": made})
        progress(made)
