"""Live Foxglove: ``foxglove=true`` on the node and the desk simulator serves what they see over Foxglove's
WebSocket protocol (``foxglove-sdk``; Foxglove's "Open connection" -> Foxglove WebSocket -> ``ws://HOST:PORT``).

Every channel carries ROS 2 messages as ROS 2 serialises them (CDR, schema ``ros2msg``), so Foxglove's panels show
them as they show a robot's topics, and the shipped layout (``docs/how-to/spade-foxglove-layout.json``) opens the
same on a live node, a recording or a robot:

==================  ================================  ==========================================================
``/map``            ``nav_msgs/msg/OccupancyGrid``    the map the node plans on
``/amcl_pose``      ``PoseWithCovarianceStamped``     the robot's pose
``/goal_pose``      ``geometry_msgs/msg/PoseStamped`` goals
``/plan``           ``nav_msgs/msg/Path``             every plan published
``/plan_window``    ``nav_msgs/msg/OccupancyGrid``    the student's window of the last plan (frame ``spade_window``)
``/plan_probability`` ``nav_msgs/msg/OccupancyGrid``  its path probabilities (0..100) in the same frame
``/tf``             ``tf2_msgs/msg/TFMessage``        ``map -> base_link`` (the robot) and ``map -> spade_window``
==================  ================================  ==========================================================
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np

from spade.ros import messages as M

__all__ = ["CHANNELS", "FoxgloveLive", "window_grids"]

log = logging.getLogger("spade.ros")

CHANNELS = {
    "map": ("/map", "nav_msgs/msg/OccupancyGrid"),
    "pose": ("/amcl_pose", "geometry_msgs/msg/PoseWithCovarianceStamped"),
    "goal": ("/goal_pose", "geometry_msgs/msg/PoseStamped"),
    "plan": ("/plan", "nav_msgs/msg/Path"),
    "window": ("/plan_window", "nav_msgs/msg/OccupancyGrid"),
    "probability": ("/plan_probability", "nav_msgs/msg/OccupancyGrid"),
    "tf": ("/tf", "tf2_msgs/msg/TFMessage"),
}
WINDOW_FRAME = "spade_window"


def _msgdef(typename: str, store: list = []) -> bytes:  # noqa: B006 - the typestore, loaded once
    if not store:
        from rosbags.typesys import Stores, get_typestore

        store.append(get_typestore(Stores.ROS2_HUMBLE))
    return store[0].generate_msgdef(typename, ros_version=2)[0].encode()


def window_grids(result: Any, ns: int | None = None) -> tuple[Any, Any] | None:
    """The student's window and its path probabilities of a plan result as ``nav_msgs/OccupancyGrid`` messages in
    the frame ``spade_window`` (the robot at its origin, x ahead: ``map -> spade_window`` is the plan's pose), or
    None when the result has no window."""
    from spade.maps.occupancy import OccupancyMap
    from spade.ros.recording import window_map

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


class FoxgloveLive:
    """A Foxglove WebSocket server fed by the node (:class:`spade.ros.node.PlannerNode` observer) or the simulator."""

    def __init__(self, host: str = "127.0.0.1", port: int = 8765) -> None:
        import foxglove

        self.context = foxglove.Context()
        self.server = foxglove.start_server(name="spade", host=host, port=int(port), context=self.context)
        self.port = self.server.port
        self.channels: dict[str, Any] = {}
        for key, (topic, typename) in CHANNELS.items():
            schema = foxglove.Schema(name=typename, encoding="ros2msg", data=_msgdef(typename))
            self.channels[key] = foxglove.Channel(topic, message_encoding="cdr", schema=schema, context=self.context)
        log.info("live Foxglove on ws://%s:%d (Foxglove: Open connection -> Foxglove WebSocket)", host, self.port)

    def log(self, key: str, msg: Any) -> None:
        if msg is not None:
            self.channels[key].log(bytes(msg.serialize()))

    # -- observer interface ----------------------------------------------------------------------------------------
    def on_message(self, name: str, msg: Any) -> None:
        if name in ("map", "goal"):
            self.log(name, msg)
        elif name == "pose":
            if type(msg).__name__ == "PoseWithCovarianceStamped":
                self.log("pose", msg)
                pose = msg.pose.pose
            else:
                pose = msg.pose
            from spade.ros.convert import quaternion_to_yaw

            q = pose.orientation
            yaw = quaternion_to_yaw(q.x, q.y, q.z, q.w)
            self.log("tf", M.tf_message((pose.position.x, pose.position.y, yaw), msg.header.frame_id or "map",
                                        "base_link"))

    def on_plan(self, event: Any, path: Any) -> None:
        self.log("plan", path)
        result = event.result
        grids = window_grids(result, event.stamp_ns)
        if grids is not None and getattr(result, "pose", None) is not None:
            self.log("tf", M.tf_message(result.pose, event.frame_id, WINDOW_FRAME, event.stamp_ns))
            self.log("window", grids[0])
            self.log("probability", grids[1])

    def close(self) -> None:
        try:
            self.server.stop()
        except Exception:  # noqa: BLE001 - shutting down
            pass
