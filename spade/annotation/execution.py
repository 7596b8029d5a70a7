"""Execution of a sketch as Nav2 would drive it, and the checks that reject a bad execution.

The sketch's waypoints are joined by a minimum-cost grid path (scikit-image ``MCP_Geometric``) on an inflated
costmap: cells closer to an obstacle than the robot radius are lethal, and a cost that decays exponentially
with the distance to obstacles (Nav2's inflation layer) pushes the path away from walls, so the executed
path bends around obstacles the way a Nav2 global planner's would. The grid path is then smoothed with a
parametric spline (scipy ``splprep``) and resampled evenly by arc length.

All geometry here is in map pixel coordinates (x = column, y = row, floats, pixel centres at integers).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np
from scipy import interpolate, ndimage
from scipy.spatial import cKDTree
from skimage.graph import MCP_Geometric
from skimage.measure import approximate_polygon

from spade.data.polyline import polyline_length, resample_polyline

FREE_CODE = 1  # spade.maps.FREE; kept local so this module works on plain uint8 grids


class Rejection(Exception):
    """A scenario attempt was rejected; ``reason`` is the counter key written into the manifest."""

    def __init__(self, reason: str, detail: str = "", points: np.ndarray | None = None) -> None:
        super().__init__(f"{reason}: {detail}" if detail else reason)
        self.reason = reason
        self.detail = detail
        self.points = points  # the executed path (map pixels) when it was driven before the check failed


@dataclass(frozen=True)
class Costmap:
    """Inflated costmap of one map, computed once per map.

    ``clearance_px``: Euclidean distance (pixels) from each free cell to the nearest non-free cell (unknown
    counts as non-free, as for Nav2 with ``track_unknown_space``), 0 on non-free cells.
    ``cost``: per-cell traversal cost for the planner, ``inf`` where the robot's centre may not go.
    """

    grid: np.ndarray
    resolution: float
    clearance_px: np.ndarray
    cost: np.ndarray
    robot_radius_px: float


def build_costmap(grid: np.ndarray, resolution: float, robot: Mapping[str, Any],
                  cost_weight: float) -> Costmap:
    """Inflate ``grid`` (uint8 codes) for a round robot.

    ``robot`` holds ``radius_m`` (inscribed radius: lethal closer than this), ``inflation_radius_m`` (no extra
    cost beyond it) and ``cost_scaling_factor`` (Nav2's exponential decay rate, 1/m). The planner's cost of a
    cell is ``1 + cost_weight * exp(-scaling * (d - radius))`` inside the inflation radius, 1 beyond.
    """
    grid = np.asarray(grid)
    if grid.ndim != 2 or grid.dtype != np.uint8:
        raise ValueError(f"grid must be a 2-D uint8 array of occupancy codes, got {grid.dtype} {grid.shape}")
    free = grid == FREE_CODE
    clearance = ndimage.distance_transform_edt(free).astype(np.float32)
    d_m = clearance * resolution
    radius = float(robot["radius_m"])
    inflation = float(robot["inflation_radius_m"])
    scaling = float(robot["cost_scaling_factor"])
    decay = np.exp(-scaling * np.clip(d_m - radius, 0.0, None))
    cost = (1.0 + cost_weight * np.where(d_m <= inflation, decay, 0.0)).astype(np.float64)
    cost[d_m < radius] = np.inf
    cost[~free] = np.inf
    return Costmap(grid, float(resolution), clearance, cost, radius / resolution)


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


def smooth_path(points: np.ndarray, smoothing_px: float, step_px: float, simplify_px: float = 0.0) -> np.ndarray:
    """Smooth a grid path and resample it evenly every ``step_px``; both ends are kept exactly.

    An 8-connected grid path runs along 0/45-degree staircases; Douglas-Peucker simplification
    (``skimage.measure.approximate_polygon``, tolerance ``simplify_px``) first straightens them (what a
    Nav2 planner's path smoother does), then a parametric spline (scipy ``splprep``, smoothing
    ``s = N * smoothing_px**2`` over the path resampled every pixel) rounds the corners.
    """
    pts = np.asarray(points, dtype=np.float64)
    if simplify_px > 0 and len(pts) > 2:
        pts = approximate_polygon(pts, tolerance=simplify_px)
        pts = resample_polyline(pts, max(2, int(np.ceil(polyline_length(pts))) + 1))
    keep = np.concatenate([[True], np.linalg.norm(np.diff(pts, axis=0), axis=1) > 1e-9])
    pts = pts[keep]
    length = polyline_length(pts)
    n_out = max(2, int(np.ceil(length / step_px)) + 1)
    if len(pts) < 4:
        return resample_polyline(pts, n_out)
    seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    u = np.concatenate([[0.0], np.cumsum(seg)]) / length
    weights = np.ones(len(pts))
    weights[[0, -1]] = 100.0  # pin the start and the goal
    tck, _ = interpolate.splprep([pts[:, 0], pts[:, 1]], u=u, w=weights, s=len(pts) * smoothing_px ** 2, k=3)
    fine = np.stack(interpolate.splev(np.linspace(0.0, 1.0, 4 * n_out), tck), axis=1)
    fine[0], fine[-1] = pts[0], pts[-1]
    return resample_polyline(fine, max(2, int(np.ceil(polyline_length(fine) / step_px)) + 1))


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
    if (costmap.grid[cells[:, 0], cells[:, 1]] != FREE_CODE).any() or clearance.min() < costmap.robot_radius_px:
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
