"""Closed-loop episodes as a ROS 2 MCAP recording for Foxglove or ``ros2 bag play``
(``python -m spade.evaluate closed_loop=true drive.mcap=episodes.mcap``).

Episodes one after another on a simulated clock (the follower's control period), one second apart, in the map
frame: the map (``/map``, latched, written again when the next episode is on another map), the demonstration
(``/demonstration``) and its goal (``/goal_pose``) at each episode's start, every plan when it was made (``/plan``),
the robot's true pose at every control step (``/robot_pose``) with the transform ``map`` -> ``base_link``
(``/tf``), and the driven path at the end (``/driven``). Written with ``rosbags``
(:class:`spade.ros.recording.BagWriter`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from spade.closedloop.simulate import Episode
from spade.ros.convert import yaw_to_quaternion
from spade.ros.recording import BagMessages, BagWriter

__all__ = ["EPISODE_TOPICS", "write_episodes_bag"]

EPISODE_TOPICS = {"/map": "nav_msgs/msg/OccupancyGrid", "/demonstration": "nav_msgs/msg/Path",
                  "/goal_pose": "geometry_msgs/msg/PoseStamped", "/plan": "nav_msgs/msg/Path",
                  "/robot_pose": "geometry_msgs/msg/PoseStamped", "/tf": "tf2_msgs/msg/TFMessage",
                  "/driven": "nav_msgs/msg/Path"}


def _tf(msgs: BagMessages, pose: np.ndarray, ns: int) -> Any:
    T = msgs.T
    x, y, yaw = (float(v) for v in pose)
    transform = T["geometry_msgs/msg/Transform"](T["geometry_msgs/msg/Vector3"](x, y, 0.0),
                                                 T["geometry_msgs/msg/Quaternion"](*yaw_to_quaternion(yaw)))
    stamped = T["geometry_msgs/msg/TransformStamped"](msgs.header("map", ns), "base_link", transform)
    return T["tf2_msgs/msg/TFMessage"]([stamped])


def write_episodes_bag(path: str | Path, episodes: list[Episode], dt_s: float, start_ns: int = 0,
                       gap_s: float = 1.0) -> Path:
    """Write ``episodes`` (module docstring) to ``path`` (a new ``.mcap`` file or rosbag2 folder)."""
    step_ns = int(round(dt_s * 1e9))
    t = int(start_ns)
    with BagWriter(path, latched=["/map"]) as bag:
        msgs = BagMessages(bag.typestore)
        shown = None
        for ep in episodes:
            sc = ep.scenario
            if shown is not sc.map:
                bag.write("/map", EPISODE_TOPICS["/map"], msgs.grid(sc.map, "map", t), t)
                shown = sc.map
            bag.write("/demonstration", EPISODE_TOPICS["/demonstration"], msgs.path(sc.demonstration, "map", t), t)
            goal = [*np.asarray(sc.goal, np.float64), 0.0]
            bag.write("/goal_pose", EPISODE_TOPICS["/goal_pose"], msgs.pose_stamped(goal, "map", t), t)
            plans = {}
            for plan in ep.plans:
                plans.setdefault(plan.step, []).append(plan)
            for k, pose in enumerate(np.asarray(ep.path, np.float64)):
                ns = t + k * step_ns
                for plan in plans.get(k, []):
                    if len(plan.waypoints) >= 2:
                        bag.write("/plan", EPISODE_TOPICS["/plan"], msgs.path(plan.waypoints, "map", ns), ns)
                bag.write("/robot_pose", EPISODE_TOPICS["/robot_pose"], msgs.pose_stamped(pose, "map", ns), ns)
                bag.write("/tf", EPISODE_TOPICS["/tf"], _tf(msgs, pose, ns), ns)
            end = t + (len(ep.path) - 1) * step_ns
            bag.write("/driven", EPISODE_TOPICS["/driven"], msgs.path(np.asarray(ep.path)[:, :2], "map", end), end)
            t = end + int(round(gap_s * 1e9))
    return Path(path)
