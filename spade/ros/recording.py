"""ROS 2 recordings: plans and node sessions written as MCAP bags, and bags replayed through the planner offline.

Written with ``rosbags`` (no ROS install), read by ``ros2 bag play``, Foxglove and ``mcap-ros2-support``:

- :func:`write_plan_bag`: one or more plans (``python -m spade.plan ... mcap=plan.mcap``): the map
  (``/map``, ``nav_msgs/OccupancyGrid``, offered transient-local as map_server does, so ``ros2 bag play`` latches it),
  the robot pose (``/start_pose``) and goal (``/goal_pose``, ``geometry_msgs/PoseStamped``), the path (``/plan``,
  ``nav_msgs/Path``), the student's window (``/plan_window``, ``geometry_msgs/PolygonStamped``) and the confidence
  (``/plan_confidence``, ``std_msgs/Float32``);
- :func:`write_test_bag`: a test set's instances (``python -m spade.evaluate ... mcap=test.mcap``), one a second in
  the robot's frame (``base_link``): the window (``/window``), the demonstration (``/ground_truth``), the student's
  path (``/prediction``, ``/prediction/planner``), each classical baseline's (``/baseline/<name>``), the goal
  (``/goal_pose``) and the APE (``/ape_cm``);
- :class:`NodeRecorder`: what ``python -m spade.ros record=BAG`` received and published, byte for byte (the DDS
  samples' CDR is ROS 2's, see ``tests/test_ros_convert.py``);
- :func:`replay_bag`: ``python -m spade.ros replay=BAG``: a rosbag2 (MCAP or SQLite, a folder or one ``.mcap``
  file) of a robot's map or costmap, pose and goals fed through :class:`spade.ros.core.PlannerCore` in recording
  order, on the recording's clock; ``out=`` writes its inputs and the plans to a new bag.

A path ending in ``.mcap`` is written as that one MCAP file; any other path as a rosbag2 folder (``metadata.yaml``
and ``<name>_0.mcap``), as ``ros2 bag record -s mcap`` writes it.
"""

from __future__ import annotations

import logging
import math
import shutil
import tempfile
import time
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from spade.ros.convert import grid_fields, path_yaws, pose_from_msg, split_stamp, yaw_to_quaternion
from spade.ros.window_messages import WINDOW_FRAME, window_grids, window_map, window_to_base_link
from spade.utils.errors import ConfigError

__all__ = ["BagError", "BagMessages", "BagWriter", "NodeRecorder", "PLAN_TOPICS", "TEST_TOPICS", "check_recording_path",
           "replay_bag", "write_plan_bag", "write_test_bag"]

log = logging.getLogger("spade.ros")

PLAN_TOPICS = {"map": "/map", "start": "/start_pose", "goal": "/goal_pose", "plan": "/plan", "window": "/plan_window",
               "confidence": "/plan_confidence"}


class BagError(ValueError):
    """A bag that cannot be written or read as asked; the message says why and what to change."""


def _typestore() -> Any:
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_HUMBLE)


def _qos(transient_local: bool) -> Any:
    from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime

    zero = QosTime(0, 0)
    return Qos(QosHistory.KEEP_LAST, 1, QosReliability.RELIABLE,
               QosDurability.TRANSIENT_LOCAL if transient_local else QosDurability.VOLATILE, zero, zero,
               QosLiveliness.AUTOMATIC, zero, False)


def check_recording_path(value: Any, key: str = "mcap") -> Path | None:
    """``mcap=``: None when unset; else a new path (a recording is never written over) in an existing folder,
    refused with a one-line :class:`ConfigError` before anything runs."""
    if value in (None, ""):
        return None
    path = Path(str(value)).expanduser()
    if path.exists():
        raise ConfigError(f"{key}={value} exists: a recording is never written over; choose a new path (a .mcap file, "
                          "or a folder name for a rosbag2 folder)")
    if not path.parent.is_dir():
        raise ConfigError(f"{key}={value}: its folder {path.parent} does not exist; create it or choose another path")
    return path


class BagWriter:
    """A ROS 2 MCAP bag being written: ``write(topic, msgtype, message_or_cdr_bytes, ns)``; topics are added on
    first use. ``path``: a new ``.mcap`` file or a new rosbag2 folder (an existing one is refused)."""

    def __init__(self, path: str | Path, latched: Iterable[str] = ("/map",)) -> None:
        from rosbags.rosbag2 import StoragePlugin, Writer

        self.path = Path(path).expanduser()
        if self.path.exists():
            raise BagError(f"{self.path} exists: a recording is never written over; choose a new path")
        if not self.path.parent.is_dir():
            raise BagError(f"{self.path.parent} is not a folder: create it or choose another path for the recording")
        self.single = self.path.suffix.lower() == ".mcap"
        self._tmp = Path(tempfile.mkdtemp(prefix=".spade-bag-", dir=self.path.parent)) if self.single else None
        self._folder = (self._tmp / self.path.stem) if self._tmp else self.path
        self.typestore = _typestore()
        self._writer = Writer(self._folder, version=9, storage_plugin=StoragePlugin.MCAP)
        self._writer.open()
        self._connections: dict[str, Any] = {}
        self._latched = set(latched)
        self.count = 0

    def write(self, topic: str, msgtype: str, message: Any, ns: int | None = None) -> None:
        """Write ``message`` (a rosbags message, or CDR bytes as ROS 2 serialises them) on ``topic``."""
        conn = self._connections.get(topic)
        if conn is None:
            conn = self._writer.add_connection(topic, msgtype, typestore=self.typestore,
                                               offered_qos_profiles=[_qos(topic in self._latched)])
            self._connections[topic] = conn
        elif conn.msgtype != msgtype:
            raise BagError(f"topic {topic} is {conn.msgtype} in this bag, not {msgtype}")
        raw = message if isinstance(message, (bytes, bytearray, memoryview)) else \
            self.typestore.serialize_cdr(message, msgtype)
        self._writer.write(conn, time.time_ns() if ns is None else int(ns), bytes(raw))
        self.count += 1

    def close(self) -> Path:
        """Finish the bag; returns the path written (the ``.mcap`` file or the folder)."""
        self._writer.close()
        if self._tmp is not None:
            files = sorted(self._folder.glob("*.mcap"))
            if len(files) != 1:
                raise BagError(f"expected one MCAP file in {self._folder}, found {len(files)}")
            files[0].replace(self.path)
            shutil.rmtree(self._tmp, ignore_errors=True)
        return self.path

    def __enter__(self) -> "BagWriter":
        return self

    def __exit__(self, *exc: object) -> None:
        if exc[0] is None:
            self.close()
        else:  # a failed recording leaves nothing behind
            try:
                self._writer.close()
            finally:
                shutil.rmtree(self._tmp or self._folder, ignore_errors=True)


# -- messages as rosbags builds them ----------------------------------------------------------------------------------
class BagMessages:
    """ROS 2 messages as ``rosbags`` instances (the same fields as :mod:`spade.ros.messages`, without DDS)."""

    def __init__(self, typestore: Any) -> None:
        self.T = typestore.types

    def time(self, ns: int) -> Any:
        return self.T["builtin_interfaces/msg/Time"](*split_stamp(ns))

    def header(self, frame: str, ns: int) -> Any:
        return self.T["std_msgs/msg/Header"](self.time(ns), frame)

    def pose(self, x: float, y: float, yaw: float) -> Any:
        T = self.T
        return T["geometry_msgs/msg/Pose"](T["geometry_msgs/msg/Point"](float(x), float(y), 0.0),
                                           T["geometry_msgs/msg/Quaternion"](*yaw_to_quaternion(float(yaw))))

    def pose_stamped(self, xy_yaw: Sequence[float], frame: str, ns: int) -> Any:
        return self.T["geometry_msgs/msg/PoseStamped"](self.header(frame, ns), self.pose(*xy_yaw))

    def grid(self, m: Any, frame: str, ns: int) -> Any:
        f = grid_fields(m)
        info = self.T["nav_msgs/msg/MapMetaData"](self.time(ns), f.resolution, f.width, f.height,
                                                  self.pose(f.origin[0], f.origin[1], f.origin[2]))
        return self.T["nav_msgs/msg/OccupancyGrid"](self.header(frame, ns), info, f.data.astype(np.int8))

    def path(self, waypoints: np.ndarray, frame: str, ns: int, goal_yaw: float | None = None) -> Any:
        pts = np.asarray(waypoints, dtype=np.float64).reshape(-1, 2)
        poses = [self.T["geometry_msgs/msg/PoseStamped"](self.header(frame, ns), self.pose(x, y, a))
                 for (x, y), a in zip(pts, path_yaws(pts, goal_yaw))]
        return self.T["nav_msgs/msg/Path"](self.header(frame, ns), poses)

    def polygon(self, corners: np.ndarray, frame: str, ns: int) -> Any:
        T = self.T
        points = [T["geometry_msgs/msg/Point32"](float(x), float(y), 0.0) for x, y in np.asarray(corners)]
        return T["geometry_msgs/msg/PolygonStamped"](self.header(frame, ns), T["geometry_msgs/msg/Polygon"](points))

    def float32(self, value: float) -> Any:
        return self.T["std_msgs/msg/Float32"](float(value))


def write_plan_bag(path: str | Path, m: Any, results: Sequence[Any], *, frame_id: str = "map",
                   start_ns: int | None = None, period_ns: int = 1_000_000_000,
                   goal_yaws: Sequence[float] | None = None, topics: Mapping[str, str] | None = None) -> Path:
    """Write plans on map ``m`` as a ROS 2 MCAP bag (see the module docstring); ``results``: :class:`PlanResult`
    objects (a failed one writes its poses, no path), one every ``period_ns`` from ``start_ns`` (now). Returns
    the path written."""
    names = {**PLAN_TOPICS, **dict(topics or {})}
    t0 = time.time_ns() if start_ns is None else int(start_ns)
    with BagWriter(path, latched=[names["map"]]) as bag:
        msgs = BagMessages(bag.typestore)
        bag.write(names["map"], "nav_msgs/msg/OccupancyGrid", msgs.grid(m, frame_id, t0), t0)
        for i, result in enumerate(results):
            ns = t0 + i * int(period_ns)
            goal_yaw = None if goal_yaws is None else goal_yaws[i]
            if result.pose is not None:
                bag.write(names["start"], "geometry_msgs/msg/PoseStamped", msgs.pose_stamped(result.pose, frame_id, ns),
                          ns)
            if result.goal is not None:
                goal = [*np.asarray(result.goal, dtype=np.float64)[:2], 0.0 if goal_yaw is None else goal_yaw]
                bag.write(names["goal"], "geometry_msgs/msg/PoseStamped", msgs.pose_stamped(goal, frame_id, ns), ns)
            if result.window is not None:
                bag.write(names["window"], "geometry_msgs/msg/PolygonStamped",
                          msgs.polygon(result.window.corners_m, frame_id, ns), ns)
            if result.success:
                bag.write(names["plan"], "nav_msgs/msg/Path",
                          msgs.path(result.waypoints, frame_id, ns, None if result.subgoal else goal_yaw), ns)
                share = float(getattr(result, "low_share", float("nan")))
                if math.isfinite(share):
                    bag.write(names["confidence"], "std_msgs/msg/Float32", msgs.float32(1.0 - share), ns)
    return Path(path)


# -- the node's session ---------------------------------------------------------------------------------------------
class NodeRecorder:
    """``python -m spade.ros record=BAG``: every message the node takes and every plan it publishes, with the time
    it happened (DDS samples are written as their CDR bytes: ROS 2's serialisation)."""

    TYPES = {"map": "nav_msgs/msg/OccupancyGrid", "goal": "geometry_msgs/msg/PoseStamped",
             "plan": "nav_msgs/msg/Path", "confidence": "std_msgs/msg/Float32"}

    def __init__(self, path: str | Path, topics: Any, pose_type: str = "amcl") -> None:
        self.topics = {k: "/" + str(getattr(topics, k)).removeprefix("rt/").lstrip("/")
                       for k in ("map", "pose", "goal", "plan", "confidence") if getattr(topics, k)}
        self.types = {**self.TYPES, "pose": "geometry_msgs/msg/PoseWithCovarianceStamped" if pose_type == "amcl"
                      else "geometry_msgs/msg/PoseStamped"}
        self.bag = BagWriter(path, latched=[self.topics["map"]])
        self.path = self.bag.path

    EXTRA = {"tf": ("/tf", "tf2_msgs/msg/TFMessage"), "window": ("/plan_window", "nav_msgs/msg/OccupancyGrid"),
             "probability": ("/plan_probability", "nav_msgs/msg/OccupancyGrid")}

    def message(self, name: str, sample: Any, ns: int | None = None) -> None:
        try:
            self.bag.write(self.topics[name], self.types[name], bytes(sample.serialize()), ns)
            if name == "pose":  # the robot in /tf too (map -> base_link), for Foxglove's 3D panel
                from spade.ros import messages as M

                frame, pose = pose_from_msg(sample)
                self._extra("tf", M.tf_message(pose, frame or "map", "base_link"), ns)
        except Exception as err:  # noqa: BLE001 - the recording must never stop the node
            log.warning("recording a %s message failed: %s: %s", name, type(err).__name__, err)

    def _extra(self, key: str, msg: Any, ns: int | None) -> None:
        topic, typename = self.EXTRA[key]
        self.bag.write(topic, typename, bytes(msg.serialize()), ns)

    def plan(self, event: Any, path: Any) -> None:
        """A published plan's student window and probabilities (``/plan_window``, ``/plan_probability``, frame
        ``spade_window``) and where that window lies (``/tf``: map -> spade_window)."""
        try:
            from spade.ros import messages as M

            grids = window_grids(event.result, event.stamp_ns)
            pose = getattr(event.result, "pose", None)
            if grids is None or pose is None:
                return
            self._extra("tf", M.tf_message(pose, event.frame_id, WINDOW_FRAME, event.stamp_ns), None)
            self._extra("window", grids[0], None)
            if grids[1] is not None:
                self._extra("probability", grids[1], None)
        except Exception as err:  # noqa: BLE001 - the recording must never stop the node
            log.warning("recording a plan's window failed: %s: %s", type(err).__name__, err)

    def close(self) -> Path:
        return self.bag.close()


# -- replay ----------------------------------------------------------------------------------------------------------
def replay_bag(core: Any, path: str | Path, topics: Mapping[str, str] | None = None,
               out: str | Path | None = None) -> dict[str, int]:
    """Feed a recording's map, pose and goal messages (``topics``: ``map``, ``pose``, ``goal`` names as in
    ``conf/ros.yaml``) to ``core`` (a :class:`~spade.ros.core.PlannerCore`) in recording order, its clock the
    recording's; ``out``: also write the inputs and each plan (``/plan``, stamped at the message that triggered it)
    to a new MCAP bag. Returns the core's counts."""
    from rosbags.highlevel import AnyReader

    names = {"map": "/map", "pose": "/amcl_pose", "goal": "/goal_pose", "plan": "/plan",
             **{k: "/" + str(v).removeprefix("rt/").lstrip("/") for k, v in dict(topics or {}).items() if v}}
    handlers = {names["map"]: core.handle_map, names["pose"]: core.handle_pose, names["goal"]: core.handle_goal}
    path = Path(path).expanduser()
    now = [0]
    core.clock = lambda: now[0] / 1e9
    core.now_ns = lambda: now[0]
    writer = BagWriter(out, latched=[names["map"]]) if out else None
    try:
        if not path.exists():
            raise BagError(f"replay={path} does not exist: pass a rosbag2 folder or an .mcap file")
        try:
            reader = AnyReader([path], default_typestore=_typestore())
            reader.open()
        except Exception as err:  # noqa: BLE001 - rosbags raises several kinds on a file that is no bag
            raise BagError(f"replay={path} cannot be read as a rosbag2 ({type(err).__name__}: {err})") from None
        try:
            wanted = [c for c in reader.connections if c.topic in handlers]
            found = sorted({c.topic for c in wanted})
            missing = [t for t in (names["map"], names["goal"]) if t not in found]
            if missing:
                have = ", ".join(sorted({f"{c.topic} ({c.msgtype})" for c in reader.connections})) or "none"
                raise BagError(f"replay={path} has no {' and no '.join(missing)} topic (topics: {have}); set "
                               "topics.map / topics.pose / topics.goal to the recording's names")
            msgs = BagMessages(writer.typestore) if writer else None
            log.info("replaying %s: %s", path, ", ".join(found))
            for conn, ns, raw in reader.messages(connections=wanted):
                now[0] = int(ns)
                try:
                    msg = reader.deserialize(raw, conn.msgtype)
                except Exception as err:  # noqa: BLE001 - a damaged message is skipped like a malformed one
                    log.warning("undecodable %s message at %d skipped: %s", conn.topic, ns, err)
                    continue
                if writer is not None:
                    writer.write(conn.topic, conn.msgtype, bytes(raw), ns)
                event = handlers[conn.topic](msg)
                if writer is not None and msgs is not None and event is not None and event.success:
                    r = event.result
                    writer.write(names["plan"], "nav_msgs/msg/Path",
                                 msgs.path(r.waypoints, event.frame_id, ns, None if r.subgoal else event.goal_yaw), ns)
        finally:
            reader.close()
    finally:
        if writer is not None:
            written = writer.close()
            log.info("replay written to %s", written)
    counts = core.counts
    log.info("replay done: %s", counts)
    return counts


# -- a test set's predictions ------------------------------------------------------------------------------------------
TEST_TOPICS = {"window": "/window", "ground_truth": "/ground_truth", "prediction": "/prediction",
               "planner": "/prediction/planner", "goal": "/goal_pose", "ape": "/ape_cm", "baseline": "/baseline"}
"""Topics of :func:`write_test_bag` (``baseline`` is the prefix of ``/baseline/<name>``)."""


def write_test_bag(path: str | Path, occupancy: np.ndarray, ground_truth: np.ndarray, goals: np.ndarray, *,
                   resolution: float | Sequence[float], robot_px: Sequence[float],
                   predictions: Sequence[np.ndarray | None] | None = None,
                   planner: Sequence[np.ndarray | None] | None = None,
                   baselines: Mapping[str, Sequence[np.ndarray | None]] | None = None,
                   ape_cm: Sequence[float | None] | None = None, frame_id: str = "base_link",
                   start_ns: int | None = None, period_ns: int = 1_000_000_000,
                   topics: Mapping[str, str] | None = None) -> Path:
    """Write test instances as a ROS 2 MCAP bag, one instance every ``period_ns`` from ``start_ns`` (now), each in
    the robot's frame (``frame_id``, the robot at the origin heading +x; window pixels converted with
    :func:`~spade.ros.window_messages.window_to_base_link`):

    - ``/window`` (``nav_msgs/OccupancyGrid``): ``occupancy`` (N, H, W) codes (0 unknown, 1 free, 2 obstacle);
    - ``/ground_truth`` (``nav_msgs/Path``): the demonstration, ``ground_truth`` (N, K, 2) window pixels;
    - ``/goal_pose`` (``geometry_msgs/PoseStamped``): ``goals`` (N, 2) window pixels (a position: yaw 0);
    - ``/prediction`` and ``/prediction/planner`` (``nav_msgs/Path``): ``predictions`` / ``planner``, one (M, 2)
      polyline or None per instance (None: nothing extracted: an empty Path at that instant, which clears what a
      viewer such as Foxglove shows of the instance before);
    - ``/baseline/<name>`` (``nav_msgs/Path``): ``baselines[name]``, as the predictions;
    - ``/ape_cm`` (``std_msgs/Float32``): ``ape_cm`` per instance (None or NaN: no message).

    ``resolution``: metres per pixel, one for all or one per instance. Pure numpy (no torch). Returns the path."""
    names = {**TEST_TOPICS, **dict(topics or {})}
    occupancy = np.asarray(occupancy)
    truth = np.asarray(ground_truth, dtype=np.float64)
    goals = np.asarray(goals, dtype=np.float64).reshape(-1, 2)
    n = len(occupancy)
    if occupancy.ndim != 3 or truth.ndim != 3 or truth.shape[-1] != 2 or len(truth) != n or len(goals) != n:
        raise ValueError(f"write_test_bag needs occupancy (N, H, W), ground_truth (N, K, 2) and goals (N, 2) of one "
                         f"N; got {occupancy.shape}, {truth.shape} and {goals.shape}")
    res = np.broadcast_to(np.asarray(resolution, dtype=np.float64).reshape(-1), (n,))
    series = {"prediction": predictions, "planner": planner, "ape": ape_cm,
              **{f"baseline/{k}": v for k, v in dict(baselines or {}).items()}}
    for key, values in series.items():
        if values is not None and len(values) != n:
            raise ValueError(f"write_test_bag: {key} holds {len(values)} values for {n} instances")
    t0 = time.time_ns() if start_ns is None else int(start_ns)
    paths = [(names["prediction"], predictions), (names["planner"], planner),
             *((f"{names['baseline'].rstrip('/')}/{k}", v) for k, v in dict(baselines or {}).items())]
    with BagWriter(path, latched=()) as bag:
        msgs = BagMessages(bag.typestore)
        for i in range(n):
            ns = t0 + i * int(period_ns)
            r = float(res[i])

            def metres(px: np.ndarray, r: float = r) -> np.ndarray:
                return window_to_base_link(px, robot_px, r)

            bag.write(names["window"], "nav_msgs/msg/OccupancyGrid",
                      msgs.grid(window_map(occupancy[i], robot_px, r), frame_id, ns), ns)
            bag.write(names["ground_truth"], "nav_msgs/msg/Path", msgs.path(metres(truth[i]), frame_id, ns), ns)
            bag.write(names["goal"], "geometry_msgs/msg/PoseStamped",
                      msgs.pose_stamped([*metres(goals[i]), 0.0], frame_id, ns), ns)
            for topic, values in paths:
                if values is None:
                    continue
                poly = values[i]
                points = metres(np.asarray(poly)) if poly is not None and len(poly) >= 2 else np.zeros((0, 2))
                bag.write(topic, "nav_msgs/msg/Path", msgs.path(points, frame_id, ns), ns)
            value = None if ape_cm is None else ape_cm[i]
            if value is not None and math.isfinite(float(value)):
                bag.write(names["ape"], "std_msgs/msg/Float32", msgs.float32(float(value)), ns)
    return Path(path)
