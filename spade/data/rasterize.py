"""Rasterisation of robot states along an executed path into the four instance images.

Every window is in the robot's frame (:mod:`spade.maps.frame`): the robot at a fixed pixel, its heading
up the image, the occupancy rotated about it. Everything is in pixels: map pixel coordinates in, window pixel
coordinates (x = column, y = row) out; each instance keeps the robot's map pose so that a prediction maps back
to the map.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from skimage.draw import disk, line
from skimage.morphology import thin

from spade.data.polyline import resample_polyline
from spade.maps.frame import RobotFrame, path_heading
from spade.maps.occupancy import UNKNOWN


@dataclass(frozen=True)
class Instance:
    """One demonstration: the window's occupancy codes, start/goal discs, path curve and polyline."""

    occupancy: np.ndarray  # (S, S) uint8 codes
    start: np.ndarray  # (S, S) bool
    goal: np.ndarray  # (S, S) bool
    path: np.ndarray  # (S, S) bool
    waypoints: np.ndarray  # (K, 2) float32, window pixel coords
    pose: tuple[float, float, float]  # the robot in the map: (x, y, yaw) in metres and radians (see robot_instance)
    state_index: int = -1  # the robot's index along its executed path (-1: not from a path)
    # (k, K, 2) window pixel polylines (spade.annotation.alternative_demonstrations)
    alternatives: np.ndarray | None = None


def crop(grid: np.ndarray, col0: int, row0: int, size: int) -> np.ndarray:
    """``size`` x ``size`` window of ``grid`` with top-left cell (col0, row0); outside the map is unknown (as in a
    rolling costmap)."""
    out = np.full((size, size), UNKNOWN, dtype=np.uint8)
    h, w = grid.shape
    r0, r1 = max(row0, 0), min(row0 + size, h)
    c0, c1 = max(col0, 0), min(col0 + size, w)
    if r0 < r1 and c0 < c1:
        out[r0 - row0:r1 - row0, c0 - col0:c1 - col0] = grid[r0:r1, c0:c1]
    return out


def draw_curve(points: np.ndarray, size: int) -> np.ndarray:
    """One 8-connected, one-pixel-wide curve through ``points`` (window pixel coords) on a size x size canvas.

    Successive points are joined with Bresenham lines (``skimage.draw.line``), which makes the curve
    8-connected; ``skimage.morphology.thin`` then removes the redundant corner pixels of staircases.
    """
    cells = np.rint(points).astype(np.int64)
    canvas = np.zeros((size, size), dtype=bool)
    if len(cells) == 1:
        canvas[cells[0, 1], cells[0, 0]] = True
        return canvas
    for (c0, r0), (c1, r1) in zip(cells[:-1], cells[1:]):
        rr, cc = line(int(r0), int(c0), int(r1), int(c1))
        canvas[rr, cc] = True
    return thin(canvas)


def draw_polyline(points: np.ndarray | None, height: int, width: int) -> np.ndarray:
    """A (H, W) float32 image with 1 on the polyline's one-pixel curve (empty for None)."""
    image = np.zeros((height, width), dtype=np.float32)
    if points is None or len(points) == 0:
        return image
    side = max(height, width)
    pts = np.clip(np.asarray(points, np.float64), 0, [width - 1, height - 1])
    image[:] = draw_curve(pts, side)[:height, :width]
    return image


def fits_robot_frame(points: np.ndarray, frame: RobotFrame, margin_px: float, lookahead_px: float = 2.0) -> bool:
    """Whether a path (map pixel coords) seen from a robot at its first point, heading along it, lies
    ``margin_px`` inside the robot-frame window."""
    pose = frame.place(points[0], path_heading(points, 0, lookahead_px))
    return frame.inside(pose.to_window(points), margin_px)


def state_indices(n_points: int, step_px: float, spacing_px: float, min_remaining_px: float) -> np.ndarray:
    """Indices of robot states every ``spacing_px`` along a path of ``n_points`` spaced ``step_px``, leaving at
    least ``min_remaining_px`` of path to drive."""
    length = (n_points - 1) * step_px
    last = length - min_remaining_px
    if last < 0:
        return np.zeros(0, dtype=np.int64)
    arc = np.arange(0.0, last + 1e-9, spacing_px)
    return np.unique(np.rint(arc / step_px).astype(np.int64))


def render(occupancy: np.ndarray, local: np.ndarray, disc_radius_px: float, num_waypoints: int,
           pose: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> Instance:
    """Instance from a window's occupancy codes and the remaining path in window pixel coordinates."""
    size = occupancy.shape[0]
    path = draw_curve(local, size)
    start = np.zeros((size, size), dtype=bool)
    goal = np.zeros((size, size), dtype=bool)
    for canvas, (x, y) in ((start, local[0]), (goal, local[-1])):
        rr, cc = disk((round(y), round(x)), max(disc_radius_px, 0.5) + 0.5, shape=(size, size))
        canvas[rr, cc] = True
    waypoints = resample_polyline(local, num_waypoints).astype(np.float32)
    return Instance(occupancy, start, goal, path, waypoints, tuple(float(v) for v in pose))  # type: ignore[arg-type]


def robot_instance(grid: np.ndarray, remaining: np.ndarray, frame: RobotFrame, margin_px: float,
                   disc_radius_px: float, num_waypoints: int, lookahead_px: float = 2.0,
                   to_world: Callable[[float, float, float], tuple[float, float, float]] | None = None
                   ) -> Instance | None:
    """Rasterise the state 'robot at remaining[0], heading along the path, goal at remaining[-1]' into its
    robot-frame window of ``grid`` (map pixel coordinates); None when the remaining path leaves the window
    (closer than ``margin_px`` to its edge). ``to_world`` turns (x_px, y_px, heading) into the pose the instance
    records, (x, y, yaw) in map metres; without it the pixel pose is kept."""
    heading = path_heading(remaining, 0, lookahead_px)
    pose = frame.place(remaining[0], heading)
    local = pose.to_window(remaining)
    if not frame.inside(local, margin_px):
        return None
    robot = (float(remaining[0][0]), float(remaining[0][1]), heading)
    return render(pose.occupancy(grid), local, disc_radius_px, num_waypoints,
                  to_world(*robot) if to_world is not None else robot)
