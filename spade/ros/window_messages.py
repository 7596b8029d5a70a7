"""The student's robot-frame window as ROS 2 data: window pixels in ``base_link`` metres, the window as an
occupancy grid in ``base_link``, and a plan's window and path probabilities as ``nav_msgs/OccupancyGrid`` messages in
the frame ``spade_window`` (what the live Foxglove server and the node's recorder publish)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from spade.maps.occupancy import OccupancyMap

__all__ = ["WINDOW_FRAME", "window_grids", "window_map", "window_to_base_link"]

WINDOW_FRAME = "spade_window"


def window_to_base_link(points_px: np.ndarray, robot_px: Sequence[float], resolution: float) -> np.ndarray:
    """Robot-frame window pixels (x = column, y = row; the robot at ``robot_px`` heading up the image, its left the
    image's left: :mod:`spade.maps.frame`) -> ``base_link`` metres (x ahead, y to the left, REP 103)."""
    pts = np.asarray(points_px, dtype=np.float64)
    rx, ry = (float(v) for v in robot_px)
    return np.stack([(ry - pts[..., 1]) * resolution, (rx - pts[..., 0]) * resolution], axis=-1)


def window_map(codes: np.ndarray, robot_px: Sequence[float], resolution: float) -> Any:
    """The window's occupancy codes (H, W) as an :class:`~spade.maps.OccupancyMap` in ``base_link``: its cells along
    +x (ahead) and +y (left), origin unrotated (what :func:`~spade.ros.convert.grid_to_map` reads back): map row ``r``
    column ``i`` is window row ``H - 1 - i``, column ``r``."""
    codes = np.asarray(codes, dtype=np.uint8)
    h, w = codes.shape
    # data[j, i] (j along +y from the origin, i along +x) = window[h-1-i, w-1-j]; the map's row 0 is its top (+y end)
    grid = codes[::-1, ::-1].T[::-1]
    corner = window_to_base_link(np.array([w - 1, h - 1], dtype=np.float64), robot_px, resolution) - 0.5 * resolution
    return OccupancyMap(np.ascontiguousarray(grid), float(resolution), (float(corner[0]), float(corner[1]), 0.0),
                        name="window")


def window_grids(result: Any, ns: int | None = None) -> tuple[Any, Any] | None:
    """The student's window and its path probabilities of a plan result as ``nav_msgs/OccupancyGrid`` messages in
    the frame ``spade_window`` (the robot at its origin, x ahead: ``map -> spade_window`` is the plan's pose), or
    None when the result has no window."""
    from spade.ros import messages as M  # cyclonedds: only where a window is published

    window = getattr(result, "window", None)
    if window is None:
        return None
    codes = window.occupancy()
    robot_px = window.pose.frame.robot_px
    resolution = float(window.map.resolution)
    geometry = window_map(codes, robot_px, resolution)
    grids = [M.occupancy_grid(geometry, WINDOW_FRAME, ns)]
    prob = getattr(result, "probability", None)
    if prob is not None and np.shape(prob) == codes.shape:
        costs = np.clip(np.rint(np.asarray(prob, np.float64) * 100), 0, 100).astype(np.int8)
        rotated = np.ascontiguousarray(costs[::-1, ::-1].T[::-1])
        pm = OccupancyMap(geometry.grid, resolution, geometry.origin, costs=rotated, name="probability")
        grids.append(M.occupancy_grid(pm, WINDOW_FRAME, ns))
    else:
        grids.append(None)
    return grids[0], grids[1]
