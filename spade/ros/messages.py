"""The ROS 2 messages the planner node exchanges, as DDS types (``cyclonedds.idl``), named as ROS 2 names them.

ROS 2 maps a message ``pkg/msg/Name`` to the DDS type ``pkg::msg::dds_::Name_`` and a topic ``/name`` to the DDS
topic ``rt/name``; its messages are *final* structs serialised as XCDR1 (plain CDR), which is what
``@annotate.final`` gives here. The field names and order follow the ``.msg`` files of ROS 2 Humble/Jazzy
(``builtin_interfaces``, ``std_msgs``, ``geometry_msgs``, ``nav_msgs``), so a ``ros2 topic echo /plan`` on the same
domain reads what this node publishes, and this node reads what ``map_server``, AMCL and RViz2 publish.

Needs the ``cyclonedds`` package (``pip install "spade[deploy]"``); the numeric conversions live in
:mod:`spade.ros.convert`, which needs no DDS. (No ``from __future__ import annotations`` here: cyclonedds reads
the field annotations as types.)
"""

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import cyclonedds.idl.annotations as annotate
from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import array, float32, float64, int8, int32, sequence, uint32

from spade.ros.convert import grid_fields, path_yaws, split_stamp, yaw_to_quaternion

__all__ = [
    "Float32", "Header", "MapMetaData", "OccupancyGrid", "Path", "Point", "Pose", "PoseStamped", "PoseWithCovariance",
    "PoseWithCovarianceStamped", "Quaternion", "ROS_TYPES", "Time", "occupancy_grid", "path", "pose", "pose_stamped",
    "pose_with_covariance", "stamp", "TFMessage", "Transform", "TransformStamped", "Vector3", "tf_message",
]


@dataclass
@annotate.final
class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: int32 = 0
    nanosec: uint32 = 0


@dataclass
@annotate.final
class Header(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Time = field(default_factory=Time)
    frame_id: str = ""


@dataclass
@annotate.final
class Float32(IdlStruct, typename="std_msgs::msg::dds_::Float32_"):
    data: float32 = 0.0


@dataclass
@annotate.final
class Point(IdlStruct, typename="geometry_msgs::msg::dds_::Point_"):
    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0


@dataclass
@annotate.final
class Quaternion(IdlStruct, typename="geometry_msgs::msg::dds_::Quaternion_"):
    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0
    w: float64 = 1.0


@dataclass
@annotate.final
class Pose(IdlStruct, typename="geometry_msgs::msg::dds_::Pose_"):
    position: Point = field(default_factory=Point)
    orientation: Quaternion = field(default_factory=Quaternion)


@dataclass
@annotate.final
class PoseStamped(IdlStruct, typename="geometry_msgs::msg::dds_::PoseStamped_"):
    header: Header = field(default_factory=Header)
    pose: Pose = field(default_factory=Pose)


@dataclass
@annotate.final
class PoseWithCovariance(IdlStruct, typename="geometry_msgs::msg::dds_::PoseWithCovariance_"):
    pose: Pose = field(default_factory=Pose)
    covariance: array[float64, 36] = field(default_factory=lambda: [0.0] * 36)


@dataclass
@annotate.final
class PoseWithCovarianceStamped(IdlStruct, typename="geometry_msgs::msg::dds_::PoseWithCovarianceStamped_"):
    header: Header = field(default_factory=Header)
    pose: PoseWithCovariance = field(default_factory=PoseWithCovariance)


@dataclass
@annotate.final
class MapMetaData(IdlStruct, typename="nav_msgs::msg::dds_::MapMetaData_"):
    map_load_time: Time = field(default_factory=Time)
    resolution: float32 = 0.0
    width: uint32 = 0
    height: uint32 = 0
    origin: Pose = field(default_factory=Pose)


@dataclass
@annotate.final
class OccupancyGrid(IdlStruct, typename="nav_msgs::msg::dds_::OccupancyGrid_"):
    header: Header = field(default_factory=Header)
    info: MapMetaData = field(default_factory=MapMetaData)
    data: sequence[int8] = field(default_factory=list)


@dataclass
@annotate.final
class Path(IdlStruct, typename="nav_msgs::msg::dds_::Path_"):
    header: Header = field(default_factory=Header)
    poses: sequence[PoseStamped] = field(default_factory=list)


@dataclass
@annotate.final
class Vector3(IdlStruct, typename="geometry_msgs::msg::dds_::Vector3_"):
    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0


@dataclass
@annotate.final
class Transform(IdlStruct, typename="geometry_msgs::msg::dds_::Transform_"):
    translation: Vector3 = field(default_factory=Vector3)
    rotation: Quaternion = field(default_factory=Quaternion)


@dataclass
@annotate.final
class TransformStamped(IdlStruct, typename="geometry_msgs::msg::dds_::TransformStamped_"):
    header: Header = field(default_factory=Header)
    child_frame_id: str = ""
    transform: Transform = field(default_factory=Transform)


@dataclass
@annotate.final
class TFMessage(IdlStruct, typename="tf2_msgs::msg::dds_::TFMessage_"):
    transforms: sequence[TransformStamped] = field(default_factory=list)


ROS_TYPES = {
    "nav_msgs/msg/OccupancyGrid": OccupancyGrid, "nav_msgs/msg/Path": Path, "nav_msgs/msg/MapMetaData": MapMetaData,
    "geometry_msgs/msg/PoseStamped": PoseStamped, "geometry_msgs/msg/PoseWithCovarianceStamped":
    PoseWithCovarianceStamped, "geometry_msgs/msg/Pose": Pose, "std_msgs/msg/Header": Header,
    "std_msgs/msg/Float32": Float32, "builtin_interfaces/msg/Time": Time, "tf2_msgs/msg/TFMessage": TFMessage,
    "geometry_msgs/msg/TransformStamped": TransformStamped,
}
"""The ROS 2 name of each type (as ``ros2 interface show`` and rosbag2 write it) -> its DDS type here."""


# -- builders -------------------------------------------------------------------------------------------------------
def stamp(ns: int | None = None) -> Time:
    """A ``builtin_interfaces/Time`` of ``ns`` nanoseconds since the epoch (now when None)."""
    sec, nanosec = split_stamp(ns)
    return Time(sec, nanosec)


def pose(x: float, y: float, yaw: float) -> Pose:
    return Pose(Point(float(x), float(y), 0.0), Quaternion(*yaw_to_quaternion(float(yaw))))


def pose_stamped(xy_yaw: Sequence[float], frame_id: str = "map", ns: int | None = None) -> PoseStamped:
    return PoseStamped(Header(stamp(ns), frame_id), pose(*xy_yaw))


def pose_with_covariance(xy_yaw: Sequence[float], frame_id: str = "map", ns: int | None = None,
                         covariance: Sequence[float] | None = None) -> PoseWithCovarianceStamped:
    cov = [float(v) for v in covariance] if covariance is not None else [0.0] * 36
    return PoseWithCovarianceStamped(Header(stamp(ns), frame_id), PoseWithCovariance(pose(*xy_yaw), cov))


def occupancy_grid(m: Any, frame_id: str = "map", ns: int | None = None) -> OccupancyGrid:
    """The ``nav_msgs/OccupancyGrid`` of an :class:`~spade.maps.OccupancyMap` (as map_server publishes it)."""
    f = grid_fields(m)
    t = stamp(ns)
    info = MapMetaData(t, f.resolution, f.width, f.height, pose(f.origin[0], f.origin[1], f.origin[2]))
    return OccupancyGrid(Header(t, frame_id), info, f.data.tolist())


def path(waypoints: Any, frame_id: str = "map", ns: int | None = None, goal_yaw: float | None = None) -> Path:
    """A ``nav_msgs/Path`` through ``waypoints`` (K, 2) metres: every pose stamped ``ns`` in ``frame_id``, oriented
    towards the next one (the last one at ``goal_yaw`` when given), as Nav2's planners publish theirs."""
    import numpy as np

    pts = np.asarray(waypoints, dtype=np.float64).reshape(-1, 2)
    t = stamp(ns)
    yaws = path_yaws(pts, goal_yaw)
    return Path(Header(t, frame_id),
                [PoseStamped(Header(Time(t.sec, t.nanosec), frame_id), pose(x, y, a)) for (x, y), a in zip(pts, yaws)])


def tf_message(xy_yaw: Sequence[float], parent: str = "map", child: str = "base_link", ns: int | None = None
               ) -> TFMessage:
    """A ``tf2_msgs/TFMessage`` with one transform ``parent`` -> ``child`` at pose ``xy_yaw`` (as ``/tf`` carries
    the robot's pose; the desk simulator and recordings publish ``map`` -> ``base_link``)."""
    x, y, yaw = (float(v) for v in xy_yaw)
    return TFMessage([TransformStamped(Header(stamp(ns), parent), child,
                                       Transform(Vector3(x, y, 0.0), Quaternion(*yaw_to_quaternion(yaw))))])
