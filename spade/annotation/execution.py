"""Execution of a sketch as Nav2 would drive it, and the checks that reject a bad execution.

The sketch's waypoints are joined by a minimum-cost grid path (scikit-image ``MCP_Geometric``) on an inflated
costmap (:mod:`spade.maps.costmap`): cells closer to an obstacle than the robot radius are lethal, and a cost
that decays exponentially with the distance to obstacles (Nav2's inflation layer) pushes the path away from
walls, so the executed path bends around obstacles the way a Nav2 global planner's would. The grid path is then
smoothed with a parametric spline (scipy ``splprep``) and resampled evenly by arc length
(:func:`spade.data.polyline.smooth_path`).

All geometry here is in map pixel coordinates (x = column, y = row, floats, pixel centres at integers).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np
from scipy.spatial import cKDTree
from skimage.graph import MCP_Geometric

from spade.data.polyline import polyline_length, resample_polyline, smooth_path
from spade.maps.costmap import Costmap, build_costmap
from spade.maps.occupancy import FREE

__all__ = ["ExecutedPath", "Rejection", "execute_sketch", "hausdorff_px", "total_turn_deg"]


class Rejection(Exception):
    """A scenario attempt was rejected; ``reason`` is the counter key written into the manifest."""

    def __init__(self, reason: str, detail: str = "", points: np.ndarray | None = None) -> None:
        super().__init__(f"{reason}: {detail}" if detail else reason)
        self.reason = reason
        self.detail = detail
        self.points = points  # the executed path (map pixels) when it was driven before the check failed


@dataclass(frozen=True)
class ExecutedPath:
    """A sketch as driven: ``points`` (N, 2) evenly spaced by ``step_px`` from start to goal."""

    points: np.ndarray
    step_px: float
    length_m: float
    turn_deg: float
    deviation_m: float
    min_clearance_m: float


def _plan(costmap: Costmap, keypoints: np.ndarray, pad_px: int) -> np.ndarray:
    """Minimum-cost grid path through the keypoints, in order; (N, 2) pixel (x, y) floats."""
    h, w = costmap.cost.shape
    cells = np.rint(keypoints[:, ::-1]).astype(np.int64)  # (row, col)
    if (cells < 0).any() or (cells[:, 0] >= h).any() or (cells[:, 1] >= w).any():
        raise Rejection("sketch_off_map", "a waypoint lies outside the map")
    if not np.isfinite(costmap.cost[cells[:, 0], cells[:, 1]]).all():
        raise Rejection("sketch_off_free", "a waypoint lies in an obstacle or closer to one than the robot radius")
    r0 = max(int(cells[:, 0].min()) - pad_px, 0)
    r1 = min(int(cells[:, 0].max()) + pad_px + 1, h)
    c0 = max(int(cells[:, 1].min()) - pad_px, 0)
    c1 = min(int(cells[:, 1].max()) + pad_px + 1, w)
    mcp = MCP_Geometric(costmap.cost[r0:r1, c0:c1], fully_connected=True)
    local = cells - np.array([r0, c0])
    pieces = []
    for a, b in zip(local[:-1], local[1:]):
        if (a == b).all():
            continue
        cum, _ = mcp.find_costs([tuple(a)], [tuple(b)], find_all_ends=True)
        if not np.isfinite(cum[tuple(b)]):
            raise Rejection("no_path", "no collision-free grid path joins two consecutive waypoints")
        trace = np.asarray(mcp.traceback(tuple(b)), dtype=np.float64)
        pieces.append(trace if not pieces else trace[1:])
    if not pieces:
        raise Rejection("no_path", "all waypoints coincide")
    rc = np.concatenate(pieces) + np.array([r0, c0])
    return rc[:, ::-1]


def total_turn_deg(points: np.ndarray, end_window_px: float) -> float:
    """Signed net heading change (degrees) between the start and the end of a path.

    Headings are unwrapped along the path, so a loop counts as 360 degrees rather than 0, and averaged over
    ``end_window_px`` of arc length at each end to ignore pixel noise.
    """
    pts = resample_polyline(points, max(8, int(polyline_length(points) / 1.0) + 1))
    d = np.diff(pts, axis=0)
    heading = np.unwrap(np.arctan2(-d[:, 1], d[:, 0]))  # y axis up, as in the map frame
    n = max(1, min(len(heading) // 4, int(round(end_window_px))))
    return float(np.rad2deg(heading[-n:].mean() - heading[:n].mean()))


def hausdorff_px(a: np.ndarray, b: np.ndarray) -> float:
    """Symmetric Hausdorff distance between two densely sampled curves."""
    da, _ = cKDTree(b).query(a)
    db, _ = cKDTree(a).query(b)
    return float(max(da.max(), db.max()))


def execute_sketch(costmap: Costmap, keypoints: np.ndarray, sketch_dense: np.ndarray, shape_turn_deg: float,
                   cfg: Mapping[str, Any]) -> ExecutedPath:
    """Drive the sketch and check it; raise :class:`Rejection` with the reason when a check fails.

    ``cfg`` is the ``execution`` config section: ``crop_pad_m``, ``simplify_px``, ``smoothing_px``, ``step_px``,
    ``max_deviation_m``, ``shape_tolerance_deg``, ``heading_window_m``.
    """
    res = costmap.resolution
    grid_path = _plan(costmap, keypoints, pad_px=int(np.ceil(float(cfg["crop_pad_m"]) / res)))
    path = smooth_path(grid_path, float(cfg["smoothing_px"]), float(cfg["step_px"]), float(cfg["simplify_px"]))
    h, w = costmap.grid.shape
    cells = np.rint(path[:, ::-1]).astype(np.int64)
    if (cells < 0).any() or (cells[:, 0] >= h).any() or (cells[:, 1] >= w).any():
        raise Rejection("non_free", "the smoothed path leaves the map", path)
    clearance = costmap.clearance_px[cells[:, 0], cells[:, 1]]
    if (costmap.grid[cells[:, 0], cells[:, 1]] != FREE).any() or clearance.min() < costmap.robot_radius_px:
        raise Rejection("non_free", f"the smoothed path comes within {clearance.min() * res:.3f} m of non-free "
                                    f"space, robot radius {costmap.robot_radius_px * res:.3f} m", path)
    deviation = hausdorff_px(path, sketch_dense) * res
    if deviation > float(cfg["max_deviation_m"]):
        raise Rejection("deviation", f"{deviation:.2f} m from the sketch > {cfg['max_deviation_m']} m", path)
    turn = total_turn_deg(path, float(cfg["heading_window_m"]) / res)
    if abs(abs(turn) - shape_turn_deg) > float(cfg["shape_tolerance_deg"]):
        raise Rejection("shape", f"net heading change {turn:.0f} deg, expected {shape_turn_deg:.0f} "
                                 f"+- {cfg['shape_tolerance_deg']} deg", path)
    return ExecutedPath(path, float(cfg["step_px"]), polyline_length(path) * res, turn, deviation,
                        float(clearance.min() * res))
