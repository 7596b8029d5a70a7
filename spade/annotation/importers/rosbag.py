"""rosbag2 importer (sqlite3 and mcap, read with the ``rosbags`` package, no ROS install needed).

A recording of a Nav2 waypoint run, as the paper's tool made it, holds:
  * ``/local_costmap/costmap`` (nav_msgs/OccupancyGrid): the rolling local window, axis-aligned;
  * ``/amcl_pose`` (geometry_msgs/PoseWithCovarianceStamped): the robot's pose;
  * ``/waypoints`` (nav_msgs/Path or geometry_msgs/PoseArray): the sketch; its last pose is the goal.
Each waypoints message starts an episode (a scenario); the episode's poses until the next waypoints message
form the driven trajectory, which is spline-smoothed and ends on the goal. Every pose sample becomes one
instance, rasterised on the latest costmap at or before it (matched by header stamp, else by record time), in the
robot's frame (spade.maps.frame: the costmap rotated about the robot, which heads along the driven path).
The costmap and the poses must share a frame (record the local costmap with ``global_frame: map``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterator, Mapping

import numpy as np
from scipy import interpolate

from spade.annotation.pipeline import RunStats
from spade.annotation.scenarios import ScenarioResult
from spade.annotation.templates import check_shape
from spade.data.polyline import polyline_length, resample_polyline
from spade.data.rasterize import Instance, robot_instance
from spade.maps.frame import RobotFrame, yaw_from_heading
from spade.maps.ros_io import codes_from_values
from spade.utils.errors import UserError

WAYPOINT_TYPES = {"nav_msgs/msg/Path", "geometry_msgs/msg/PoseArray"}


class RosbagImportError(UserError, ValueError):
    """A recording cannot be imported; the message names what is missing and the setting to change."""


@dataclass(frozen=True)
class _Costmap:
    stamp: int
    codes: np.ndarray  # (H, W) uint8, row 0 at the top (max y)
    resolution: float
    origin: tuple[float, float]
    frame: str


def _stamp(msg: Any, record_ns: int) -> int:
    header = getattr(msg, "header", None)
    if header is not None:
        ns = int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)
        if ns > 0:
            return ns
    return int(record_ns)


def _yaw(q: Any) -> float:
    return float(np.arctan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z)))


def read_bag(path: str | Path, topics: Mapping[str, str]) -> tuple[list[_Costmap], np.ndarray, list[tuple[int, np.ndarray, str]], str]:
    """Costmaps, poses (N, 3: stamp ns, x, y) and waypoint messages (stamp, (M, 2) xy, frame) of one bag;
    also returns the poses' frame."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"rosbag {path} does not exist")
    costmaps: list[_Costmap] = []
    poses: list[tuple[int, float, float]] = []
    pose_frame = ""
    waypoints: list[tuple[int, np.ndarray, str]] = []
    with AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as reader:
        available = {c.topic: c.msgtype for c in reader.connections}
        for key, topic in topics.items():
            if topic not in available:
                listing = ", ".join(f"{t} ({m})" for t, m in sorted(available.items())) or "none"
                raise RosbagImportError(
                    f"rosbag {path} has no topic {topic!r} (rosbag.{key}); its topics: {listing}. Record it, or "
                    f"point rosbag.{key}= at the topic that holds it."
                )
        if available[topics["waypoints_topic"]] not in WAYPOINT_TYPES:
            raise RosbagImportError(f"{topics['waypoints_topic']} is {available[topics['waypoints_topic']]}; "
                                    f"expected one of {sorted(WAYPOINT_TYPES)}")
        wanted = [c for c in reader.connections if c.topic in topics.values()]
        for conn, record_ns, raw in reader.messages(connections=wanted):
            msg = reader.deserialize(raw, conn.msgtype)
            stamp = _stamp(msg, record_ns)
            if conn.topic == topics["costmap_topic"]:
                info = msg.info
                if abs(_yaw(info.origin.orientation)) > 1e-6:
                    raise RosbagImportError(f"costmap at {stamp} ns is rotated; a rolling local costmap is axis-aligned")
                values = np.asarray(msg.data, dtype=np.int8).reshape(int(info.height), int(info.width))
                costmaps.append(_Costmap(stamp, values[::-1], float(info.resolution),
                                         (float(info.origin.position.x), float(info.origin.position.y)),
                                         msg.header.frame_id))
            elif conn.topic == topics["pose_topic"]:
                p = msg.pose.pose.position
                poses.append((stamp, float(p.x), float(p.y)))
                pose_frame = msg.header.frame_id
            else:
                items = msg.poses
                pts = np.array([[q.pose.position.x, q.pose.position.y] if hasattr(q, "pose") else
                                [q.position.x, q.position.y] for q in items], dtype=np.float64).reshape(-1, 2)
                waypoints.append((stamp, pts, msg.header.frame_id))
    costmaps.sort(key=lambda c: c.stamp)
    waypoints.sort(key=lambda w: w[0])
    pose_arr = np.array(sorted(poses), dtype=np.float64).reshape(-1, 3)
    return costmaps, pose_arr, waypoints, pose_frame


def smooth_trajectory(xy: np.ndarray, goal: np.ndarray, smoothing_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Spline-smooth the driven positions, ending on the goal; returns (fine curve, index of each pose on it)."""
    pts = np.concatenate([xy, goal[None]]) if np.linalg.norm(xy[-1] - goal) > 1e-6 else xy.copy()
    keep = np.concatenate([[True], np.linalg.norm(np.diff(pts, axis=0), axis=1) > 1e-9])
    pts_k = pts[keep]
    seg = np.linalg.norm(np.diff(pts_k, axis=0), axis=1)
    u = np.concatenate([[0.0], np.cumsum(seg)])
    total = u[-1]
    n_fine = max(2, int(np.ceil(total / 0.005)) + 1)  # 5 mm
    if len(pts_k) >= 4 and total > 0:
        w = np.ones(len(pts_k))
        w[[0, -1]] = 100.0
        tck, _ = interpolate.splprep([pts_k[:, 0], pts_k[:, 1]], u=u / total, w=w, s=len(pts_k) * smoothing_m ** 2)
        fine = np.stack(interpolate.splev(np.linspace(0, 1, n_fine), tck), axis=1)
        fine[0], fine[-1] = pts_k[0], pts_k[-1]
    else:
        fine = resample_polyline(pts_k, n_fine)
    # Index of each recorded pose on the fine curve, by arc-length fraction of the raw trajectory.
    raw_u = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
    frac = raw_u[: len(xy)] / max(raw_u[-1], 1e-12)
    idx = np.minimum(np.rint(frac * (len(fine) - 1)).astype(np.int64), len(fine) - 2)
    return fine, idx


def rosbag_instances(cfg: Mapping[str, Any], stats: RunStats,
                     progress: Callable[[int], None] = lambda n: None) -> Iterator[tuple[Instance, str, str, str]]:
    """Instances of every bag in ``rosbag.paths`` (see the module docstring)."""
    rb = cfg["rosbag"]
    shape = check_shape(str(cfg["shape"]))
    paths = [rb["paths"]] if isinstance(rb["paths"], (str, Path)) else list(rb["paths"])
    topics = {k: str(rb[k]) for k in ("costmap_topic", "pose_topic", "waypoints_topic")}
    size = int(cfg["window"]["size_px"])
    resolution = float(cfg["window"]["resolution_m"])
    k_wp = int(cfg["num_waypoints"])
    for bag in paths:
        costmaps, poses, waypoint_msgs, pose_frame = read_bag(bag, topics)
        name = Path(bag).stem if Path(bag).is_file() else Path(bag).name
        map_id = str(rb.get("map_id") or name)
        if not costmaps or not len(poses) or not waypoint_msgs:
            raise RosbagImportError(f"rosbag {bag}: {len(costmaps)} costmaps, {len(poses)} poses, "
                                    f"{len(waypoint_msgs)} waypoint messages; each of the three topics needs messages")
        frames = {c.frame for c in costmaps} | {w[2] for w in waypoint_msgs} | {pose_frame}
        if len(frames - {""}) > 1:
            raise RosbagImportError(f"rosbag {bag}: costmap, pose and waypoints frames differ ({sorted(frames)}); "
                                    "record the local costmap with global_frame: map (no TF lookup is done)")
        for cm in costmaps:
            if abs(cm.resolution - resolution) > 1e-6:
                raise RosbagImportError(f"rosbag {bag}: costmap resolution {cm.resolution} m/px differs from "
                                        f"window.resolution_m={resolution}; set window.resolution_m={cm.resolution}")
        stamps = np.array([c.stamp for c in costmaps])
        disc = float(cfg["instances"]["disc_radius_m"]) / resolution
        for e, (t0, wps, _) in enumerate(waypoint_msgs):
            t1 = waypoint_msgs[e + 1][0] if e + 1 < len(waypoint_msgs) else np.iinfo(np.int64).max
            result = ScenarioResult(f"{name}/{shape}{e:03d}", map_id, shape, e)
            sel = (poses[:, 0] >= t0) & (poses[:, 0] < t1)
            if sel.sum() < 2 or len(wps) == 0:
                result.rejections["too_few_poses"] += 1
                stats.add(result)
                continue
            ep = poses[sel]
            fine, idx = smooth_trajectory(ep[:, 1:], wps[-1], float(rb["spline_smoothing_m"]))
            made = 0
            for j, (stamp, _, _) in enumerate(ep):
                c = int(np.searchsorted(stamps, stamp, side="right")) - 1
                if c < 0:
                    result.rejections["no_costmap_yet"] += 1
                    continue
                cm = costmaps[c]
                inst = _instance(cm, fine[idx[j]:], size, disc, k_wp, int(rb["occupied_threshold"]), result)
                if inst is None:
                    continue
                made += 1
                yield inst, shape, map_id, result.scenario_id
            stats.add(result)
            stats.scenarios.append({"scenario_id": result.scenario_id, "map_id": map_id, "shape": shape,
                                    "instances": made, "length_m": round(polyline_length(fine), 3)})
            progress(made)


def _instance(cm: _Costmap, remaining_m: np.ndarray, size: int, disc_px: float, k_wp: int, threshold: int,
              result: ScenarioResult) -> Instance | None:
    """The robot-frame window (spade.maps.frame) of a robot at ``remaining_m[0]`` heading along the driven
    path, cut out of the costmap it was recorded with (cells outside the costmap are unknown)."""
    h, w = cm.codes.shape
    res = cm.resolution
    col = (remaining_m[:, 0] - cm.origin[0]) / res - 0.5
    row = (h - 1) - ((remaining_m[:, 1] - cm.origin[1]) / res - 0.5)
    pts = np.stack([col, row], axis=1)
    pts = resample_polyline(pts, max(2, int(np.ceil(polyline_length(pts) / 0.5)) + 1))  # every half pixel
    start = (float(remaining_m[0, 0]), float(remaining_m[0, 1]))
    inst = robot_instance(codes_from_values(cm.codes, threshold), pts, RobotFrame.for_size(size), 0.0, disc_px, k_wp,
                          to_world=lambda x, y, h: (*start, yaw_from_heading(h)))
    if inst is None:
        result.rejections["path_outside_window"] += 1
        return None
    if (inst.occupancy[inst.path] != 1).any():
        result.rejections["path_non_free"] += 1
        return None
    return inst
