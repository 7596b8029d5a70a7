"""What the planner node does with each message, without any transport: a map, a pose and a goal in, plans out.

:class:`PlannerCore` keeps the latest map (``nav_msgs/OccupancyGrid``, converted by
:func:`spade.ros.convert.grid_to_map`), the robot's latest pose and the active goal, and plans with a
:class:`spade.planner.Planner` when

- a new goal arrives (once a map and a pose are known; a goal that arrives first waits for them);
- the robot leaves the current plan: its pose lies farther than ``replan_distance_m`` from the plan's polyline (or,
  after a failed attempt, that far from where it was tried);
- the robot has moved ``replan_every_m`` since the last plan (when set: Nav2's behaviour tree replans at a fixed
  rate; the closed-loop evaluation, :mod:`spade.closedloop`, uses this rule with it);
- the robot nears the end of a plan to a sub-goal (``far_goal: clip``: the goal lay beyond the student's window),
  within ``subgoal_replan_m`` of it;
- a new map arrives while a goal is active (``replan_on_map``; a rolling costmap replans at its own rate).

Every replan passes the robot's previous plan to the same goal (``previous``; an action goal: the last action
plan to the same goal) so that the planner's replanning prior (``planner.replan_prior``,
:class:`spade.deploy.student_planner.Planner`) keeps the turn it chose; a new goal, or a failed attempt, plans
afresh. The goal is dropped once the robot is within ``goal_reached_m`` of it, and after a query that cannot succeed
however the robot moves (a goal off the map or on an obstacle). Every message that cannot be used (malformed, in
another frame than the map's: the node has no TF) is logged and dropped; nothing a message holds raises out of a
``handle_*`` method. The DDS node (:mod:`spade.ros.node`) and the offline replay (:mod:`spade.ros.replay`) feed it.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from spade.maps.occupancy import OccupancyMap
from spade.ros.convert import MessageError, grid_to_map, pose_from_msg

__all__ = ["CoreSettings", "PlanEvent", "PlannerCore", "check_option", "distance_to_polyline", "off_plan_reason",
           "replan_trigger"]

log = logging.getLogger("spade.ros")

# Two action goals this close (metres) are the same goal: the later query replans the earlier one's plan.
SAME_GOAL_M = 1e-3
# A query that fails with one of these fails the same way from any pose: the goal is dropped.
GOAL_FAILURES = ("goal_outside_map", "goal_not_free")


@dataclass(frozen=True)
class CoreSettings:
    replan_distance_m: float = 0.5       # the robot this far from the plan: plan again
    goal_reached_m: float = 0.25         # the robot this near the goal: the goal is done
    subgoal_replan_m: float = 1.0        # this near the end of a plan to a sub-goal: plan on towards the goal
    replan_on_map: bool = True           # a new map while a goal is active: plan again
    min_replan_interval_s: float = 0.5   # pose-triggered plans at most this often
    replan_every_m: float | None = None  # plan again after the robot moved this far since the last plan (None: never)
    lethal_threshold: int = 100          # OccupancyGrid values at or above it are obstacles (Nav2's default)
    map_frame: str | None = None         # None: the map message's frame_id ("map" when it is empty)
    max_map_cells: int = 25_000_000      # a map larger than this (as given, or at the student's resolution) is refused

    def __post_init__(self) -> None:
        check_settings(self)


# name -> (kind, lower bound, lower bound inclusive, may be None); kinds: float, int, bool, str
_SETTING_TYPES: dict[str, tuple[str, float | None, bool, bool]] = {
    "replan_distance_m": ("float", 0.0, False, False), "goal_reached_m": ("float", 0.0, False, False),
    "subgoal_replan_m": ("float", 0.0, True, False), "replan_on_map": ("bool", None, True, False),
    "min_replan_interval_s": ("float", 0.0, True, False), "replan_every_m": ("float", 0.0, False, True),
    "lethal_threshold": ("int", 1, True, False), "map_frame": ("str", None, True, True),
    "max_map_cells": ("int", 1, True, False),
}


def check_option(key: str, value: Any, kind: str, low: float | None = None, inclusive: bool = True,
                 nullable: bool = False, *, high: float | None = None, example: Any = None) -> Any:
    """``value`` as ``kind`` (float, int, bool, str) in range, or ValueError naming ``key``, what it takes and the
    fix: booleans are strict (true / false), numbers finite."""
    if value is None:
        if nullable:
            return None
        raise ValueError(f"{key}=null: give a value ({kind})")
    if kind == "bool":
        if isinstance(value, bool):
            return value
        raise ValueError(f"{key}={value!r}: a boolean; pass {key}=true or {key}=false")
    if kind == "str":
        if isinstance(value, str):
            return value
        raise ValueError(f"{key}={value!r}: a string; quote it ({key}='...')")
    if isinstance(value, bool) or not isinstance(value, (int, float)) or (kind == "int" and isinstance(value, float)
                                                                         and not float(value).is_integer()):
        what = "an integer" if kind == "int" else "a number"
        hint = example if example is not None else (low if low is not None and inclusive else 1)
        raise ValueError(f"{key}={value!r}: {what}; pass e.g. {key}={hint}")
    number = int(value) if kind == "int" else float(value)
    if not math.isfinite(float(number)):
        raise ValueError(f"{key}={value!r}: a finite number")
    if low is not None and (number < low or (number == low and not inclusive)):
        raise ValueError(f"{key}={value!r}: must be {'>=' if inclusive else '>'} {low:g}")
    if high is not None and number > high:
        raise ValueError(f"{key}={value!r}: must be <= {high:g}")
    return number


def check_settings(settings: Any, prefix: str = "node.") -> None:
    """Type and range every field of a :class:`CoreSettings` (ValueError naming the option and the fix)."""
    for key, (kind, low, inclusive, nullable) in _SETTING_TYPES.items():
        default = CoreSettings.__dataclass_fields__[key].default
        value = check_option(prefix + key, getattr(settings, key), kind, low, inclusive, nullable,
                             high=100 if key == "lethal_threshold" else None, example=default)
        object.__setattr__(settings, key, value)


@dataclass
class PlanEvent:
    """One planning attempt: why it ran, its :class:`~spade.planner.PlanResult`, the frame and stamp to publish
    the path with, and how long the query took."""

    trigger: str
    result: Any
    frame_id: str
    stamp_ns: int
    seconds: float
    goal_yaw: float | None = None
    error: str | None = None  # the planner raised (query only): its message

    @property
    def success(self) -> bool:
        return bool(self.result.success)

    @property
    def confidence(self) -> float:
        """1 - the share of the path's length through pixels the network gave p < 0.5 (NaN when unknown)."""
        share = float(getattr(self.result, "low_share", float("nan")))
        return 1.0 - share if math.isfinite(share) else float("nan")


def distance_to_polyline(point: np.ndarray, line: np.ndarray) -> float:
    """The distance (same units) from ``point`` (2,) to the polyline ``line`` (K, 2)."""
    p = np.asarray(point, dtype=np.float64)[:2]
    pts = np.asarray(line, dtype=np.float64).reshape(-1, 2)
    if len(pts) == 0:
        return math.inf
    if len(pts) == 1:
        return float(np.linalg.norm(pts[0] - p))
    a, b = pts[:-1], pts[1:]
    d = b - a
    den = np.maximum((d * d).sum(axis=1), 1e-18)
    t = np.clip(((p - a) * d).sum(axis=1) / den, 0.0, 1.0)
    return float(np.linalg.norm(a + t[:, None] * d - p, axis=1).min())


def replan_trigger(settings: CoreSettings, pose: np.ndarray, plan: np.ndarray | None, subgoal: bool,
                   tried_at: np.ndarray | None, seconds_since_try: float) -> str | None:
    """Why the robot at ``pose`` should plan again (a short reason), or None: the node's rule for a pose that
    arrives while a goal is active, after its first plan. ``plan``: the waypoints of the last successful plan
    (None after a failed attempt); ``subgoal``: that plan ends at a sub-goal; ``tried_at``: the pose of the last
    attempt; ``seconds_since_try``: the time since it."""
    if seconds_since_try < settings.min_replan_interval_s:
        return None
    return off_plan_reason(settings, pose, plan, subgoal, tried_at)


def off_plan_reason(settings: CoreSettings, pose: np.ndarray, plan: np.ndarray | None, subgoal: bool,
                    tried_at: np.ndarray | None) -> str | None:
    """:func:`replan_trigger` without the interval: why a pose calls for a new plan, or None."""
    moved = math.inf if tried_at is None else float(np.linalg.norm(pose[:2] - tried_at[:2]))
    if plan is not None:
        off = distance_to_polyline(pose[:2], plan)
        if off > settings.replan_distance_m:
            return f"off the plan by {off:.2f} m"
        if subgoal and np.linalg.norm(pose[:2] - plan[-1]) <= settings.subgoal_replan_m:
            return "near the sub-goal"
        if settings.replan_every_m is not None and moved >= settings.replan_every_m:
            return f"moved {moved:.2f} m since the last plan"
        return None
    if moved > settings.replan_distance_m:
        return "moved since the last attempt"
    return None


@dataclass
class _State:
    map: OccupancyMap | None = None
    frame: str = "map"
    pose: np.ndarray | None = None
    goal: np.ndarray | None = None      # (x, y, yaw)
    plan: np.ndarray | None = None      # waypoints of the last successful plan to the active goal
    subgoal: bool = False
    tried_at: np.ndarray | None = None  # the pose of the last attempt
    tried_time: float = -math.inf
    pending: str | None = None          # a pose called for a plan before min_replan_interval_s passed: plan then
    counts: dict[str, int] = field(default_factory=dict)
    query_goal: np.ndarray | None = None  # the last action (query) goal planned to (x, y) ...
    query_plan: np.ndarray | None = None  # ... and the waypoints of that plan (None after a failure)


class PlannerCore:
    """The node's logic (see the module docstring). ``planner``: a :class:`spade.planner.Planner` (anything with its
    ``plan(map, pose, goal, previous=None)``); ``clock``: seconds, monotonic (tests pass their own); ``now_ns``: the
    stamp of the published paths (wall-clock nanoseconds, as ROS's system time)."""

    def __init__(self, planner: Any, settings: CoreSettings | None = None, *,
                 clock: Callable[[], float] = time.monotonic, now_ns: Callable[[], int] = time.time_ns) -> None:
        self.planner = planner
        self.settings = settings or CoreSettings()
        self.clock, self.now_ns = clock, now_ns
        self.state = _State()

    # -- bookkeeping ---------------------------------------------------------------------------------------------
    def _count(self, key: str) -> None:
        self.state.counts[key] = self.state.counts.get(key, 0) + 1

    @property
    def counts(self) -> dict[str, int]:
        """Messages and outcomes so far: ``map``, ``pose``, ``goal``, ``malformed``, ``wrong_frame``, ``plan``,
        ``no_path``, ``reached``."""
        return dict(self.state.counts)

    # -- messages ------------------------------------------------------------------------------------------------
    def handle_map(self, msg: Any) -> PlanEvent | None:
        """A ``nav_msgs/OccupancyGrid``: the map to plan on from now on (a malformed one is logged, the previous
        map kept)."""
        too_big = self.map_too_big(msg)
        if too_big is not None:
            self._count("too_big")
            log.warning("map refused (keeping the previous one): %s", too_big)
            return None
        t0 = time.perf_counter()
        try:
            m = grid_to_map(msg, lethal_threshold=self.settings.lethal_threshold)
        except MessageError as err:
            self._count("malformed")
            log.warning("malformed map ignored (keeping the previous one): %s", err)
            return None
        except Exception as err:  # noqa: BLE001 - a message must never stop the node
            self._count("malformed")
            log.warning("unreadable map ignored: %s: %s", type(err).__name__, err)
            return None
        seconds = time.perf_counter() - t0
        if seconds > 1.0:
            log.warning("converting the map took %.1f s; a smaller map (a costmap window) keeps the node responsive",
                        seconds)
        self._count("map")
        first = self.state.map is None
        self.state.map = m
        self.state.frame = self.settings.map_frame or str(msg.header.frame_id) or "map"
        level = logging.INFO if first or self.state.counts["map"] % 50 == 0 else logging.DEBUG
        log.log(level, "map received: %d x %d cells at %.3f m/cell, origin (%.2f, %.2f), frame %r", m.width, m.height,
                m.resolution, m.origin[0], m.origin[1], self.state.frame)
        if self.state.goal is not None and (first or self.settings.replan_on_map):
            return self._plan("map")
        return None

    def map_too_big(self, msg: Any) -> str | None:
        """Why a ``nav_msgs/OccupancyGrid`` is too large to take (its cells, or its cells once resampled to the
        student's resolution, above ``max_map_cells``: memory and time grow with them), or None."""
        try:
            width, height = int(msg.info.width), int(msg.info.height)
            resolution = float(msg.info.resolution)
        except Exception:  # noqa: BLE001 - malformed: grid_to_map says why
            return None
        limit = int(self.settings.max_map_cells)
        if width * height > limit:
            return (f"{width} x {height} cells ({width * height:,}) exceed node.max_map_cells={limit:,}; publish a "
                    "smaller map (a costmap window around the robot) or raise node.max_map_cells")
        target = float(getattr(self.planner, "resolution", 0.0) or 0.0)
        if target > 0 and math.isfinite(resolution) and resolution > target:
            scale = resolution / target
            w, h = math.ceil(width * scale), math.ceil(height * scale)
            if w * h > limit:
                return (f"{width} x {height} cells at {resolution:g} m/cell become {w:,} x {h:,} cells "
                        f"({w * h:,}) at the student's {target:g} m/cell, more than node.max_map_cells={limit:,} "
                        "(memory and time grow with them); publish a smaller map (a costmap window around the "
                        "robot) or raise node.max_map_cells")
        return None

    def _read_pose(self, msg: Any, what: str) -> np.ndarray | None:
        """The pose (x, y, yaw) of a pose or goal message, counted as ``what``; None (counted and logged) when it
        is malformed or in another frame."""
        try:
            frame, pose = pose_from_msg(msg)
        except MessageError as err:
            self._count("malformed")
            log.warning("malformed %s ignored: %s", what, err)
            return None
        if frame not in ("", self.state.frame):
            self._count("wrong_frame")
            log.warning("%s in frame %r ignored: the map is in frame %r and this node has no TF; publish the %s in "
                        "the map frame", what, frame, self.state.frame, what)
            return None
        self._count(what)
        return pose

    def handle_pose(self, msg: Any) -> PlanEvent | None:
        """A ``geometry_msgs/PoseWithCovarianceStamped`` (AMCL) or ``PoseStamped``: the robot's pose."""
        pose = self._read_pose(msg, "pose")
        if pose is None:
            return None
        first = self.state.pose is None
        self.state.pose = pose
        if first:
            log.info("robot pose received: (%.2f, %.2f) m, yaw %.2f rad", *pose)
        s = self.state
        if s.goal is None:
            return None
        if np.linalg.norm(pose[:2] - s.goal[:2]) <= self.settings.goal_reached_m:
            self._count("reached")
            log.info("goal (%.2f, %.2f) reached", s.goal[0], s.goal[1])
            s.goal, s.plan = None, None
            return None
        if first:
            return self._plan("pose")
        if s.tried_at is None and s.plan is None:
            return None  # no attempt yet (a goal that waits for the map)
        reason = off_plan_reason(self.settings, pose, s.plan, s.subgoal, s.tried_at)
        if reason is None:
            s.pending = None
            return None
        if self.clock() - s.tried_time < self.settings.min_replan_interval_s:
            s.pending = reason  # too soon: plan once the interval has passed (tick), even if no other pose comes
            return None
        return self._plan(reason)

    def tick(self) -> PlanEvent | None:
        """Called by the node between messages: plans for a pose that called for it before
        ``min_replan_interval_s`` had passed, as soon as it has (a robot standing still sends no new pose)."""
        s = self.state
        if s.pending is None or s.goal is None or s.pose is None:
            return None
        if self.clock() - s.tried_time < self.settings.min_replan_interval_s:
            return None
        reason, s.pending = s.pending, None
        return self._plan(f"{reason} (after the interval)")

    def query(self, pose: Any, goal: Any, trigger: str = "query") -> PlanEvent:
        """One plan on the latest map from ``pose`` (x, y, yaw) to ``goal`` (x, y[, yaw]) that leaves the topic
        goal's state alone (the action server's goals; Nav2's behaviour tree asks again for the same goal about
        once a second, so the last query plan to the same goal is passed as ``previous``); a planner that raises
        gives ``error``."""
        s = self.state
        goal = np.asarray(goal, dtype=np.float64).reshape(-1)
        goal_yaw = float(goal[2]) if goal.size > 2 else None
        t0 = time.perf_counter()
        if s.map is None:
            return PlanEvent(trigger, None, s.frame, self.now_ns(), 0.0, goal_yaw, error="no map yet")
        same_goal = s.query_goal is not None and float(np.linalg.norm(s.query_goal - goal[:2])) <= SAME_GOAL_M
        previous = s.query_plan if same_goal else None
        s.query_goal, s.query_plan = goal[:2].copy(), None
        try:
            result = self.planner.plan(s.map, np.asarray(pose, dtype=np.float64), goal[:2], previous=previous)
        except Exception as err:  # noqa: BLE001 - a query the planner cannot take must not stop the node
            log.error("planning failed (%s): %s: %s", trigger, type(err).__name__, err)
            return PlanEvent(trigger, None, s.frame, self.now_ns(), time.perf_counter() - t0, goal_yaw,
                             error=f"{type(err).__name__}: {err}")
        if result.success:
            s.query_plan = np.asarray(result.waypoints, dtype=np.float64)
        return PlanEvent(trigger, result, s.frame, self.now_ns(), time.perf_counter() - t0, goal_yaw)

    def handle_goal(self, msg: Any) -> PlanEvent | None:
        """A ``geometry_msgs/PoseStamped`` goal (RViz2's "2D Goal Pose"): plan to it."""
        goal = self._read_pose(msg, "goal")
        if goal is None:
            return None
        self.state.goal, self.state.plan, self.state.subgoal = goal, None, False
        log.info("goal received: (%.2f, %.2f) m", goal[0], goal[1])
        if self.state.map is None or self.state.pose is None:
            log.info("waiting for %s before planning", " and ".join(
                w for w, v in (("a map", self.state.map), ("the robot's pose", self.state.pose)) if v is None))
            return None
        return self._plan("goal")

    # -- planning ------------------------------------------------------------------------------------------------
    def _plan(self, trigger: str) -> PlanEvent | None:
        s = self.state
        assert s.goal is not None
        if s.map is None or s.pose is None:
            return None
        s.tried_at, s.tried_time, s.pending = s.pose.copy(), self.clock(), None
        t0 = time.perf_counter()
        try:
            result = self.planner.plan(s.map, s.pose, s.goal[:2], previous=s.plan)
        except Exception as err:  # noqa: BLE001 - a query the planner cannot take must not stop the node
            self._count("no_path")
            log.error("planning failed (%s): %s: %s", trigger, type(err).__name__, err)
            s.plan = None
            return None
        seconds = time.perf_counter() - t0
        event = PlanEvent(trigger, result, s.frame, self.now_ns(), seconds, goal_yaw=float(s.goal[2]))
        if not result.success:
            self._count("no_path")
            s.plan = None
            dropped = result.code in GOAL_FAILURES
            log.warning("no path (%s, %.0f ms): %s: %s%s", trigger, 1000 * seconds, result.code, result.reason,
                        "; goal dropped" if dropped else "")
            if dropped:
                s.goal = None
            return event
        self._count("plan")
        s.plan, s.subgoal = np.asarray(result.waypoints, dtype=np.float64), bool(result.subgoal)
        log.info("plan (%s): %d poses, %.2f m%s, confidence %.2f%s%s, %.0f ms", trigger, len(result.waypoints),
                 result.length_m, " to a sub-goal" if result.subgoal else "", event.confidence,
                 " (shortest-path fallback)" if result.fallback else "",
                 " (the previous plan is blocked: planned afresh)" if getattr(result, "prior", None) == "blocked"
                 else "", 1000 * seconds)
        return event
