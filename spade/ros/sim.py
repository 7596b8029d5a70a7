"""The desk simulator, ``python -m spade.ros sim map=MAP [model=student.onnx] ...``: a robot without a robot.

It plays map_server, AMCL and RViz2 for the planner node on DDS (no ROS install): publishes the map
(``nav_msgs/OccupancyGrid``, latched), the robot's pose (``PoseWithCovarianceStamped`` on ``/amcl_pose`` and
``map -> base_link`` on ``/tf``) at ``rate_hz``, and goals (``PoseStamped`` on ``/goal_pose``) from a list or at
random; the robot follows the node's latest ``/plan`` with the closed-loop evaluation's pure-pursuit follower
(:mod:`spade.deploy.follower`). With ``use_action=true`` the goals go through the ``ComputePathToPose`` action
instead (:class:`spade.ros.action.ActionClient`, re-sent every ``action_replan_s`` as Nav2's behaviour tree does).
Given ``model=``, it starts the node itself (``python -m spade.ros``) as a child process. ``MAP``: a ROS map yaml
or a procedural spec such as ``warehouse:1`` (the tutorials' maps).

``foxglove=true`` serves what the simulator sees (map, pose, goals, the node's plans, ``/tf``) on its own live
Foxglove server (``foxglove_port``, 8766); ``node_foxglove=true`` turns on the node's server too
(``node_foxglove_port``, 8765: the student's window and path probabilities of each plan besides);
:mod:`spade.ros.live`.

A goal is reached within ``goal_reached_m``; a goal not reached within ``goal_timeout_s`` is given up. The run
ends after the last goal (or ``max_seconds``) with one summary line; the exit status is 0 when every goal was
reached, 1 otherwise.
"""

from __future__ import annotations

import logging
import math
import os
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from spade.maps import FREE, OccupancyMap
from spade.utils.errors import ConfigError
from spade.annotation.sources import parse_procedural
from spade.deploy.follower import follow_step, FollowerSettings
from spade.maps import generate_map, load_ros_map, MapFormatError
from spade.ros.convert import nanoseconds
from spade.ros.core import check_option
from spade.ros.launch import NODE_FOXGLOVE_PORT, SIM_FOXGLOVE_PORT, domain_id, foxglove_options, require_dds

__all__ = ["SimRobot", "SimSettings", "pick_free_pose", "run_sim", "sim_map"]

log = logging.getLogger("spade.ros")


@dataclass
class SimSettings:
    rate_hz: float = 10.0
    speed_mps: float = 0.22
    goal_reached_m: float = 0.25
    goal_timeout_s: float = 60.0
    clearance_m: float = 0.3
    goal_distance_m: tuple[float, float] = (1.0, 3.0)


@dataclass
class SimRobot:
    """The simulated robot: a pose that follows the latest plan with the closed loop's follower."""

    pose: np.ndarray
    map: OccupancyMap
    settings: SimSettings = field(default_factory=SimSettings)
    plan: np.ndarray | None = None
    collisions: int = 0

    def step(self) -> np.ndarray:
        if self.plan is None or len(self.plan) < 2:
            return self.pose
        follower = FollowerSettings(speed_mps=self.settings.speed_mps, dt_s=1.0 / self.settings.rate_hz)
        new = follow_step(self.pose, self.plan, follower)
        if not _free(self.map, new[:2]):
            if _free(self.map, self.pose[:2]):
                self.collisions += 1
                log.warning("sim: the robot would enter an obstacle at (%.2f, %.2f); it stops", new[0], new[1])
            self.plan = None
            return self.pose
        self.pose = new
        return self.pose


def _free(m: OccupancyMap, xy: np.ndarray) -> bool:
    col, row = np.rint(m.world_to_pixel(np.asarray(xy, np.float64)[:2])).astype(int)
    return bool(0 <= row < m.height and 0 <= col < m.width and m.grid[row, col] == FREE)


def _clearance(m: OccupancyMap) -> np.ndarray:
    from scipy.ndimage import distance_transform_edt

    return distance_transform_edt(m.grid == FREE) * m.resolution


def pick_free_pose(m: OccupancyMap, rng: np.random.Generator, clearance_m: float, near: np.ndarray | None = None,
                   distance_m: tuple[float, float] = (1.0, 3.0), tries: int = 5000,
                   clearance: np.ndarray | None = None) -> np.ndarray:
    """A random pose (x, y, yaw) on a free cell ``clearance_m`` from obstacles (``distance_m`` from ``near`` when
    given, the yaw then facing away from it)."""
    clear = _clearance(m) if clearance is None else clearance
    rows, cols = np.nonzero(clear >= clearance_m)
    if len(rows) == 0:
        raise ValueError(f"map {m.name!r} has no free cell {clearance_m} m from obstacles; lower clearance_m")
    for _ in range(tries):
        k = int(rng.integers(len(rows)))
        xy = m.pixel_to_world(np.array([cols[k], rows[k]], np.float64))
        if near is None:
            return np.array([xy[0], xy[1], float(rng.uniform(-math.pi, math.pi))])
        d = float(np.linalg.norm(xy - near[:2]))
        if distance_m[0] <= d <= distance_m[1]:
            return np.array([xy[0], xy[1], math.atan2(xy[1] - near[1], xy[0] - near[0])])
    raise ValueError(f"no free cell {distance_m[0]}..{distance_m[1]} m from ({near[0]:.2f}, {near[1]:.2f}) "
                     f"in {tries} tries; give goals= or another goal_distance_m")


def _path_xy(msg: Any) -> np.ndarray:
    return np.array([[p.pose.position.x, p.pose.position.y] for p in msg.poses], np.float64).reshape(-1, 2)


def _triples(value: Any, key: str) -> list[np.ndarray]:
    try:
        out = [np.asarray([float(v) for v in item], np.float64) for item in value]
    except (TypeError, ValueError):
        out = []
    if not out or any(p.shape not in ((2,), (3,)) or not np.isfinite(p).all() for p in out):
        raise ValueError(f"{key}={value!r}: a list of poses [[x, y, yaw], ...] in map metres (yaw optional), "
                         f"or {key}=random")
    return [np.append(p, 0.0) if p.shape == (2,) else p for p in out]


def sim_map(spec: Any) -> OccupancyMap:
    """The simulator's map: a ROS map yaml (and its image) or a procedural ``kind:seed`` spec such as
    ``warehouse:1``; a missing file or a bad spec is one :class:`~spade.utils.errors.ConfigError` line."""
    fix = "give a ROS map yaml (map_server format) or a generator spec such as warehouse:101"
    if spec in (None, ""):
        raise ConfigError(f"map is not set; {fix}")
    try:
        procedural = parse_procedural(str(spec))
    except ValueError as exc:
        raise ConfigError(f"map={spec}: {exc}") from None
    if procedural is not None:
        return generate_map(*procedural)
    path = Path(str(spec)).expanduser()
    if not path.is_file():
        raise ConfigError(f"map={spec} does not exist; {fix}")
    try:
        return load_ros_map(path)
    except MapFormatError as exc:
        raise ConfigError(f"map={spec}: {exc}") from None


def run_sim(cfg: Any) -> int:
    """Run the simulator of ``cfg`` (conf/ros_sim.yaml); returns the exit status (0: every goal reached)."""
    from omegaconf import OmegaConf

    c = OmegaConf.to_container(cfg, resolve=True)
    try:
        settings = SimSettings(
            rate_hz=check_option("rate_hz", c.get("rate_hz", 10.0), "float", 0.0, False),
            speed_mps=check_option("speed_mps", c.get("speed_mps", 0.22), "float", 0.0, False),
            goal_reached_m=check_option("goal_reached_m", c.get("goal_reached_m", 0.25), "float", 0.0, False),
            goal_timeout_s=check_option("goal_timeout_s", c.get("goal_timeout_s", 60.0), "float", 0.0, False),
            clearance_m=check_option("clearance_m", c.get("clearance_m", 0.3), "float", 0.0, True))
        num_goals = check_option("num_goals", c.get("num_goals", 3), "int", 1)
        seed = check_option("seed", c.get("seed", 0), "int")
        use_action = check_option("use_action", c.get("use_action", False), "bool")
        max_seconds = check_option("max_seconds", c.get("max_seconds"), "float", 0.0, False, nullable=True)
        replan_s = check_option("action_replan_s", c.get("action_replan_s", 1.0), "float", 0.0, False)
        distance = c.get("goal_distance_m", [1.0, 3.0])
        if not (isinstance(distance, list) and len(distance) == 2):
            raise ValueError(f"goal_distance_m={distance!r}: [min, max] metres")
        settings.goal_distance_m = (check_option("goal_distance_m[0]", distance[0], "float", 0.0),
                                    check_option("goal_distance_m[1]", distance[1], "float", 0.0))
        if settings.goal_distance_m[0] > settings.goal_distance_m[1]:
            raise ValueError(f"goal_distance_m={list(distance)!r}: the minimum exceeds the maximum, e.g. "
                             "goal_distance_m=[1.0,3.0]")
        goals_cfg = c.get("goals", "random")
        goals = None if goals_cfg in (None, "random") else _triples(goals_cfg, "goals")
        start_cfg = c.get("start")
        start = None if start_cfg in (None, "random") else _triples([start_cfg], "start")[0]
    except ValueError as err:
        raise ConfigError(f"{err}; set it on the command line or in conf/ros_sim.yaml (whose comments give each "
                          "option's meaning)") from None
    map_path = c.get("map")
    if not map_path:
        raise ConfigError("map: no map; pass map=MAP.yaml (a ROS map: yaml + image) or a procedural spec such as "
                          "map=warehouse:1")
    domain = domain_id(cfg)
    foxglove = foxglove_options(cfg, default_port=SIM_FOXGLOVE_PORT)
    node_foxglove = foxglove_options(cfg, "node_foxglove", NODE_FOXGLOVE_PORT)
    if node_foxglove is not None and not c.get("model_path"):
        raise ConfigError("node_foxglove=true: the simulator starts no node without model=; pass model=student.onnx, "
                          "or start the node yourself with foxglove=true")
    if foxglove is not None and node_foxglove is not None and foxglove["port"] == node_foxglove["port"] != 0:
        raise ConfigError(f"foxglove_port and node_foxglove_port are both {foxglove['port']}: the simulator's and the "
                          "node's Foxglove servers need a port each; give them two")
    require_dds("python -m spade.ros sim")
    topics = {"map": "/map", "pose": "/amcl_pose", "goal": "/goal_pose", "plan": "/plan", **(c.get("topics") or {})}
    m = sim_map(map_path)
    rng = np.random.default_rng(seed)
    clear = _clearance(m)
    for name, p in ([("start", start)] if start is not None else []) + [(f"goal {i}", g)
                                                                         for i, g in enumerate(goals or [])]:
        if not _free(m, p[:2]):
            raise ConfigError(f"{name} ({p[0]:.2f}, {p[1]:.2f}) is not on a free cell of map {map_path}")
    if start is None:
        start = pick_free_pose(m, rng, settings.clearance_m, clearance=clear)
    robot = SimRobot(start.copy(), m, settings)

    live = None
    if foxglove is not None:
        from spade.ros.live import SIM_CHANNELS, FoxgloveLive

        live = FoxgloveLive(**foxglove, channels=SIM_CHANNELS)
    node_proc = None
    if c.get("model_path"):
        args = [sys.executable, "-m", "spade.ros", f"model_path={c['model_path']}", f"domain_id={domain}",
                *[str(a) for a in (c.get("node_args") or [])]]
        if node_foxglove is not None:
            args += ["foxglove=true", f"foxglove_host={node_foxglove['host']}",
                     f"foxglove_port={node_foxglove['port']}"]
        if use_action:
            args += ["action.enabled=true", f"action.name={c.get('action_name', '/compute_path_to_pose')}",
                     f"action.distro={c.get('action_distro', 'jazzy')}"]
        log.info("sim: starting the node: %s", " ".join(args[1:]))
        node_proc = subprocess.Popen(args, env=os.environ.copy())
    try:
        return _run(cfg, c, m, robot, goals, num_goals, rng, clear, topics, domain, use_action, replan_s,
                    max_seconds, live, node_proc)
    finally:
        if live is not None:
            live.close()
        if node_proc is not None:
            node_proc.terminate()
            try:
                node_proc.wait(20)
            except subprocess.TimeoutExpired:
                node_proc.kill()


def _run(cfg: Any, c: dict, m: OccupancyMap, robot: SimRobot, goals: list[np.ndarray] | None, num_goals: int,
         rng: np.random.Generator, clear: np.ndarray, topics: dict, domain: int, use_action: bool, replan_s: float,
         max_seconds: float | None, live: Any, node_proc: Any) -> int:
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.pub import DataWriter
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic

    from spade.ros import messages as M
    from spade.ros.dds import make_qos, ros_topic

    s = robot.settings
    p = DomainParticipant(domain)
    map_writer = DataWriter(p, Topic(p, ros_topic(topics["map"]), M.OccupancyGrid), qos=make_qos(True, True, 1))
    pose_writer = DataWriter(p, Topic(p, ros_topic(topics["pose"]), M.PoseWithCovarianceStamped),
                             qos=make_qos(True, True, 1))
    tf_writer = DataWriter(p, Topic(p, "rt/tf", M.TFMessage), qos=make_qos(True, False, 100))
    goal_writer = DataWriter(p, Topic(p, ros_topic(topics["goal"]), M.PoseStamped), qos=make_qos(True, False, 10))
    plan_reader = DataReader(p, Topic(p, ros_topic(topics["plan"]), M.Path), qos=make_qos(True, False, 10))
    client = None
    if use_action:
        from spade.ros.action import ActionClient

        client = ActionClient(p, str(c.get("action_name", "/compute_path_to_pose")),
                              str(c.get("action_distro", "jazzy")))
    grid = M.occupancy_grid(m, "map")
    map_writer.write(grid)
    if live is not None:
        live.on_message("map", grid)
    log.info("sim: map %s (%d x %d cells at %.3f m/cell), robot at (%.2f, %.2f, %.2f); waiting for the node's plan "
             "subscription", m.name, m.width, m.height, m.resolution, *robot.pose)
    end = None if max_seconds is None else time.monotonic() + max_seconds
    wait_end = time.monotonic() + 120.0
    while not (goal_writer.get_matched_subscriptions() and plan_reader.get_matched_publications()) and not use_action:
        if time.monotonic() > wait_end or (end is not None and time.monotonic() > end):
            log.error("sim: no planner node on DDS domain %d (topics %s, %s)", domain, topics["goal"], topics["plan"])
            return 1
        if node_proc is not None and node_proc.poll() is not None:
            log.error("sim: the node exited (status %s)", node_proc.returncode)
            return 1
        time.sleep(0.1)
    if client is not None and not client.wait_for_server(120.0):
        log.error("sim: no ComputePathToPose server %s on DDS domain %d", c.get("action_name"), domain)
        return 1
    dt = 1.0 / s.rate_hz
    reached, given_up, plans, t_start = 0, 0, 0, time.monotonic()
    k = 0
    while (goals is None and k < num_goals) or (goals is not None and k < len(goals)):
        goal = goals[k] if goals is not None else pick_free_pose(m, rng, s.clearance_m, robot.pose,
                                                                 s.goal_distance_m, clearance=clear)
        k += 1
        robot.plan = None
        sent_ns = time.time_ns()
        log.info("sim: goal %d: (%.2f, %.2f, %.2f)", k, *goal)
        msg = M.pose_stamped(goal, "map")
        if client is None:
            goal_writer.write(msg)
        if live is not None:  # a topic goal or an action goal: the viewer shows it either way
            live.on_message("goal", msg)
        goal_end, next_action = time.monotonic() + s.goal_timeout_s, 0.0
        ok = False
        while time.monotonic() < goal_end and (end is None or time.monotonic() < end):
            tick = time.monotonic()
            ns = time.time_ns()
            pose_msg = M.pose_with_covariance(robot.pose, "map", ns)
            pose_writer.write(pose_msg)
            tf_writer.write(M.tf_message(robot.pose, "map", "base_link", ns))
            if live is not None:
                live.on_message("pose", pose_msg)
            if client is not None and tick >= next_action:
                next_action = tick + replan_s
                try:
                    reply = client.plan(goal, timeout_s=10.0)
                except (TimeoutError, RuntimeError) as err:
                    log.warning("sim: action goal failed: %s", err)
                else:
                    if reply.status == 4 and reply.result.path.poses:
                        robot.plan, plans = _path_xy(reply.result.path), plans + 1
                    else:
                        log.warning("sim: action goal ended with status %d%s", reply.status,
                                    f", error {reply.result.error_code}" if hasattr(reply.result, "error_code")
                                    else "")
            for sample in plan_reader.take(N=16):
                if sample is None or not getattr(getattr(sample, "sample_info", None), "valid_data", True):
                    continue
                if live is not None:  # every plan the node publishes (an action goal's too, as planner_server)
                    live.on_plan(None, sample)
                fresh = nanoseconds(sample.header.stamp) >= sent_ns - 50_000_000
                if client is None and fresh and len(sample.poses) >= 2:
                    robot.plan, plans = _path_xy(sample), plans + 1
            robot.step()
            if float(np.linalg.norm(robot.pose[:2] - goal[:2])) <= s.goal_reached_m:
                ok = True
                break
            if node_proc is not None and node_proc.poll() is not None:
                log.error("sim: the node exited (status %s)", node_proc.returncode)
                return 1
            time.sleep(max(0.0, dt - (time.monotonic() - tick)))
        if ok:
            reached += 1
            log.info("sim: goal %d reached: robot at (%.2f, %.2f) after %.1f s", k, robot.pose[0], robot.pose[1],
                     s.goal_timeout_s - (goal_end - time.monotonic()))
        else:
            given_up += 1
            log.warning("sim: goal %d not reached (robot at (%.2f, %.2f))", k, robot.pose[0], robot.pose[1])
        if end is not None and time.monotonic() >= end:
            break
    total = k
    log.info("sim: %d/%d goals reached in %.1f s, %d plans followed, %d collisions", reached, total,
             time.monotonic() - t_start, plans, robot.collisions)
    print(f"sim: {reached}/{total} goals reached, {plans} plans followed, {robot.collisions} collisions")
    return 0 if reached == total and total > 0 else 1
