"""The robot frame of an instance window: the robot at a fixed pixel, its heading pointing up the image.

An axis-aligned window hides the robot's heading, and an L or U between a start and a goal is then ambiguous
(its corner can lie on either side of the start-goal line); a model trained on such windows learns a blur of
both mirror images. SKIPP's data, which the paper builds on, are robot-centred and robot-oriented, and so are
SPADE's: every window is cut out of the map rotated about the robot so that

- the robot sits at pixel ``robot_px = (size / 2, 3 * size / 4)`` (x = column, y = row; (32, 48) in a 64 px
  window), leaving three quarters of the window ahead of it and a quarter behind (a U's way back can end
  behind the robot);
- its heading points up the image (towards row 0); its left is the image's left.

The rotation is a proper rotation of the map image (no mirror). Occupancy is resampled conservatively: each
window pixel looks at 2 x 2 points of its footprint in the map and is an obstacle if any point is, unknown if
any point is unknown (or off the map), free only if all four are free. A 0.5 px lattice puts a point inside
every map cell whatever the angle, so no obstacle cell (a thin wall) is ever skipped, and free space is never
invented. Geometry is in map *pixel* coordinates (x = column, y = row, pixel centres at integers); a heading is
the angle ``atan2(d_row, d_col)`` of the direction of travel in those coordinates. ROS yaw (counter-clockwise,
y up) converts with :func:`heading_from_yaw` / :func:`yaw_from_heading` (row 0 is the top of a map image).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from spade.maps.occupancy import FREE, OCCUPIED, UNKNOWN

FRAME_KIND = "robot"
_SUBSAMPLES = np.array([[-0.25, -0.25], [0.25, -0.25], [-0.25, 0.25], [0.25, 0.25]])


def heading_from_yaw(yaw: float) -> float:
    """Map-pixel heading of a ROS yaw (radians, counter-clockwise from +x with y up): rows grow downwards."""
    return -float(yaw)


def yaw_from_heading(heading: float) -> float:
    """ROS yaw of a map-pixel heading (the inverse of :func:`heading_from_yaw`)."""
    return -float(heading)


def path_heading(points: np.ndarray, index: int = 0, lookahead_px: float = 2.0) -> float:
    """Heading (map-pixel angle) of travel at ``points[index]``: towards the first later point at least
    ``lookahead_px`` away (the last point when none is)."""
    pts = np.asarray(points, dtype=np.float64)
    origin = pts[index]
    ahead = pts[index + 1:]
    if len(ahead) == 0:
        ahead = pts[index:index + 1] - (pts[index - 1:index] - origin) if index > 0 else pts[index:index + 1]
    dist = np.linalg.norm(ahead - origin, axis=1)
    far = np.flatnonzero(dist >= lookahead_px)
    target = ahead[far[0]] if len(far) else ahead[-1]
    d = target - origin
    if not np.any(d):
        raise ValueError("cannot take a heading from a path whose points coincide")
    return float(math.atan2(d[1], d[0]))


@dataclass(frozen=True)
class RobotFrame:
    """The window convention: side ``size`` px, robot at ``robot_px``, heading up."""

    size: int
    robot_px: tuple[float, float]

    @classmethod
    def for_size(cls, size: int) -> "RobotFrame":
        size = int(size)
        if size < 8:
            raise ValueError(f"window.size_px={size} is too small for a robot-frame window; use at least 32")
        return cls(size, (size / 2.0, 0.75 * size))

    def to_json(self) -> dict[str, Any]:
        return {"kind": FRAME_KIND, "size_px": self.size, "robot_px": [float(v) for v in self.robot_px],
                "heading": "up"}

    @classmethod
    def from_json(cls, info: Mapping[str, Any]) -> "RobotFrame":
        if info.get("kind") != FRAME_KIND or info.get("heading", "up") != "up":
            raise ValueError(f"not a SPADE robot frame: {dict(info)}")
        return cls(int(info["size_px"]), tuple(float(v) for v in info["robot_px"]))  # type: ignore[arg-type]

    def place(self, robot: np.ndarray, heading: float) -> "WindowPose":
        """The window of a robot at map pixel ``robot`` (x, y) heading ``heading`` (map-pixel angle)."""
        return WindowPose(self, np.asarray(robot, dtype=np.float64).reshape(2).copy(), float(heading))

    def inside(self, points: np.ndarray, margin_px: float) -> bool:
        """Whether every window point (x, y) lies at least ``margin_px`` inside the window."""
        pts = np.asarray(points, dtype=np.float64)
        lo, hi = margin_px, self.size - 1 - margin_px
        return bool(((pts >= lo) & (pts <= hi)).all())


@dataclass(frozen=True)
class WindowPose:
    """Where one robot-frame window lies in a map: the robot's map pixel and heading."""

    frame: RobotFrame
    robot: np.ndarray  # (2,) map pixel (x, y)
    heading: float  # map-pixel angle of the direction of travel

    def _rotation(self) -> np.ndarray:
        """R with R @ (map offset) = window offset: the heading direction goes to (0, -1)."""
        a = -math.pi / 2.0 - self.heading
        c, s = math.cos(a), math.sin(a)
        return np.array([[c, -s], [s, c]])

    def to_window(self, points_map: np.ndarray) -> np.ndarray:
        """Map pixel coordinates (..., 2) -> window pixel coordinates (..., 2)."""
        pts = np.asarray(points_map, dtype=np.float64)
        return (pts - self.robot) @ self._rotation().T + np.asarray(self.frame.robot_px)

    def to_map(self, points_window: np.ndarray) -> np.ndarray:
        """Window pixel coordinates (..., 2) -> map pixel coordinates (..., 2)."""
        pts = np.asarray(points_window, dtype=np.float64)
        return (pts - np.asarray(self.frame.robot_px)) @ self._rotation() + self.robot

    def occupancy(self, grid: np.ndarray) -> np.ndarray:
        """(size, size) uint8 codes of the window, resampled conservatively (see the module docstring)."""
        size = self.frame.size
        rows, cols = np.mgrid[0:size, 0:size]
        centres = np.stack([cols, rows], axis=-1).reshape(-1, 1, 2).astype(np.float64)
        samples = self.to_map(centres + _SUBSAMPLES[None])  # (S*S, 4, 2) map pixel coords
        cells = np.rint(samples).astype(np.int64)
        h, w = grid.shape
        on_map = (cells[..., 0] >= 0) & (cells[..., 0] < w) & (cells[..., 1] >= 0) & (cells[..., 1] < h)
        codes = np.full(on_map.shape, UNKNOWN, dtype=np.uint8)
        codes[on_map] = grid[cells[..., 1][on_map], cells[..., 0][on_map]]
        out = np.full(codes.shape[0], FREE, dtype=np.uint8)
        out[(codes == UNKNOWN).any(axis=1)] = UNKNOWN
        out[(codes == OCCUPIED).any(axis=1)] = OCCUPIED
        return out.reshape(size, size)
