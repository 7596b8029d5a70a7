"""ROS 2 messages <-> SPADE's map and path types, with numpy only (no DDS, no ROS).

The readers take any object with the ROS 2 field names (a :mod:`spade.ros.messages` DDS sample, a message that
``rosbags`` deserialised from a bag, a ``SimpleNamespace`` in a test): ``msg.info.width``, ``msg.pose.position.x``
and so on. A message that cannot be what it claims (sizes that disagree, a non-finite number, a zero quaternion,
a value outside an ``OccupancyGrid``'s -1..100) raises :class:`MessageError`, which the node logs and survives.

Conventions (``nav_msgs/OccupancyGrid``): ``data`` is row-major starting with the cell at ``info.origin`` (the map's
lower-left corner), so its first row is the *bottom* of the map, whereas :class:`~spade.maps.OccupancyMap` keeps row 0
at the top (as the map image does): the rows are flipped on the way in and out. Values: -1 unknown, 0..100 the
occupancy probability in percent (a costmap's scaled cost); a value at or above ``lethal_threshold`` (Nav2's
``lethal_cost_threshold``, 100 by default) is an obstacle, other known values are free, as Nav2's ``StaticLayer``
reads a map with ``trinary_costmap`` and ``track_unknown_space`` (:func:`spade.maps.ros_io.codes_from_values`).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from spade.maps.occupancy import FREE, OCCUPIED, UNKNOWN, OccupancyMap
from spade.maps.ros_io import codes_from_values

__all__ = [
    "GridFields", "MessageError", "grid_fields", "grid_to_map", "nanoseconds", "path_yaws", "pose_from_msg",
    "quaternion_to_yaw", "split_stamp", "yaw_to_quaternion",
]

MAX_CELLS = 100_000_000  # 10 km x 10 km at 1 m/px, or 500 m x 500 m at 5 cm/px: anything larger is refused


class MessageError(ValueError):
    """A message whose contents cannot be what its type says; the text says what is wrong with it."""


# -- time ---------------------------------------------------------------------------------------------------------
def split_stamp(ns: int | None = None) -> tuple[int, int]:
    """(sec, nanosec) of a time in nanoseconds since the epoch (now when None), as ``builtin_interfaces/Time``."""
    ns = time.time_ns() if ns is None else int(ns)
    return ns // 1_000_000_000, ns % 1_000_000_000


def nanoseconds(stamp: Any) -> int:
    """Nanoseconds of a ``builtin_interfaces/Time``."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


# -- orientation ----------------------------------------------------------------------------------------------------
def yaw_to_quaternion(yaw: float) -> tuple[float, float, float, float]:
    """(x, y, z, w) of a rotation by ``yaw`` radians about +z (ROS: counter-clockwise seen from above)."""
    return 0.0, 0.0, math.sin(yaw / 2.0), math.cos(yaw / 2.0)


def quaternion_to_yaw(x: float, y: float, z: float, w: float) -> float:
    """The yaw (rotation about +z, radians in (-pi, pi]) of a quaternion; a zero or non-finite one is a
    :class:`MessageError` (RViz2 and AMCL always send unit quaternions)."""
    q = np.array([x, y, z, w], dtype=np.float64)
    norm = float(np.linalg.norm(q))
    if not np.isfinite(q).all() or norm < 1e-9:
        raise MessageError(f"orientation ({x}, {y}, {z}, {w}) is not a rotation (zero or non-finite quaternion)")
    x, y, z, w = q / norm
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def path_yaws(waypoints: np.ndarray, goal_yaw: float | None = None) -> np.ndarray:
    """A yaw per waypoint: the direction to the next one (as Nav2's planners orient a path's poses); the last
    takes ``goal_yaw`` when given, else the direction of the last segment."""
    pts = np.asarray(waypoints, dtype=np.float64).reshape(-1, 2)
    if len(pts) == 0:
        return np.zeros(0)
    if len(pts) == 1:
        return np.array([0.0 if goal_yaw is None else float(goal_yaw)])
    d = np.diff(pts, axis=0)
    yaws = np.arctan2(d[:, 1], d[:, 0])
    # A repeated point has no direction of its own: it takes the previous one.
    still = np.linalg.norm(d, axis=1) < 1e-12
    for i in np.flatnonzero(still):
        yaws[i] = yaws[i - 1] if i > 0 else 0.0
    last = yaws[-1] if goal_yaw is None else float(goal_yaw)
    return np.append(yaws, last)


# -- poses ----------------------------------------------------------------------------------------------------------
def pose_from_msg(msg: Any) -> tuple[str, np.ndarray]:
    """(frame_id, (x, y, yaw)) of a ``geometry_msgs/PoseStamped`` or ``PoseWithCovarianceStamped``."""
    try:
        frame = str(msg.header.frame_id)
        pose = msg.pose.pose if hasattr(msg.pose, "pose") else msg.pose
        p, q = pose.position, pose.orientation
        xyz = np.array([p.x, p.y, p.z], dtype=np.float64)
        yaw = quaternion_to_yaw(q.x, q.y, q.z, q.w)
    except MessageError:
        raise
    except (AttributeError, TypeError, ValueError) as err:
        raise MessageError(f"not a pose message ({type(err).__name__}: {err})") from None
    if not np.isfinite(xyz).all():
        raise MessageError(f"position ({xyz[0]}, {xyz[1]}, {xyz[2]}) is not finite")
    return frame, np.array([xyz[0], xyz[1], yaw])


# -- maps -----------------------------------------------------------------------------------------------------------
def grid_to_map(msg: Any, *, lethal_threshold: int = 100, name: str | None = None) -> OccupancyMap:
    """The :class:`~spade.maps.OccupancyMap` of a ``nav_msgs/OccupancyGrid`` (a map or a costmap); its 0..100
    values are kept in ``costs``. Raises :class:`MessageError` on a malformed or unsupported grid."""
    try:
        info = msg.info
        width, height = int(info.width), int(info.height)
        resolution = float(info.resolution)
        o = info.origin
        origin = np.array([o.position.x, o.position.y], dtype=np.float64)
        q = o.orientation
        data = msg.data
        frame = str(msg.header.frame_id)
    except (AttributeError, TypeError, ValueError) as err:
        raise MessageError(f"not an OccupancyGrid ({type(err).__name__}: {err})") from None
    if width <= 0 or height <= 0:
        raise MessageError(f"grid of {width} x {height} cells: a map needs at least one cell")
    if width * height > MAX_CELLS:
        raise MessageError(f"grid of {width} x {height} cells exceeds {MAX_CELLS} cells")
    if not (math.isfinite(resolution) and resolution > 0):
        raise MessageError(f"resolution {resolution} m/cell: it must be a finite number > 0")
    if not np.isfinite(origin).all():
        raise MessageError(f"origin ({origin[0]}, {origin[1]}) is not finite")
    yaw = quaternion_to_yaw(q.x, q.y, q.z, q.w)
    if abs(yaw) > 1e-6:
        raise MessageError(f"origin yaw {yaw:.4f} rad: only maps whose origin is not rotated are supported "
                           "(map_server and Nav2's costmaps publish yaw 0)")
    values = np.frombuffer(data, dtype=np.int8) if isinstance(data, (bytes, bytearray, memoryview)) \
        else np.asarray(data)
    if values.ndim != 1 or values.size != width * height:
        raise MessageError(f"data holds {values.size} values for {width} x {height} = {width * height} cells")
    if values.size and (values.min() < -1 or values.max() > 100):
        raise MessageError(f"data holds values from {values.min()} to {values.max()}; an OccupancyGrid holds -1 "
                           "(unknown) and 0..100")
    values = values.astype(np.int8).reshape(height, width)[::-1]  # the message's first row is the map's bottom row
    return OccupancyMap(codes_from_values(values, lethal_threshold), resolution, (origin[0], origin[1], 0.0),
                        name=name or frame or "map", costs=np.ascontiguousarray(values))


@dataclass(frozen=True)
class GridFields:
    """What a ``nav_msgs/OccupancyGrid`` of a map holds: ``data`` row-major from the origin's row, int8."""

    width: int
    height: int
    resolution: float
    origin: tuple[float, float, float]
    data: np.ndarray


def grid_fields(m: OccupancyMap) -> GridFields:
    """The ``OccupancyGrid`` fields of a map: its ``costs`` when it keeps them, else its codes as map_server
    publishes a trinary map (unknown -1, free 0, obstacle 100)."""
    if m.costs is not None:
        values = np.asarray(m.costs, dtype=np.int8)
    else:
        values = np.full(m.grid.shape, -1, dtype=np.int8)
        values[m.grid == FREE] = 0
        values[m.grid == OCCUPIED] = 100
        values[m.grid == UNKNOWN] = -1
    origin = (float(m.origin[0]), float(m.origin[1]), float(m.origin[2]))
    return GridFields(m.width, m.height, float(m.resolution), origin, np.ascontiguousarray(values[::-1]).reshape(-1))
