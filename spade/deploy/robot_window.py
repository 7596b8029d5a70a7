"""The student's robot-frame window of a query: the map resampled to the student's resolution and rotated about the
robot, and the points that go to and from it (map metres <-> window pixels).

The student only ever saw the windows of the annotation tool, which are in the robot's frame
(:mod:`spade.maps.frame`): the robot at a fixed pixel, its heading up the image, the map rotated about it.
A query (map, robot pose, goal) is turned into exactly such a window by :class:`WindowPlanner`:

- the map is resampled to the student's resolution (``OccupancyMap.resampled``: obstacles never vanish);
- the robot pose (x, y, yaw) in map metres (ROS yaw: counter-clockwise from the map's +x axis) places the
  window: ``frame.place(world_to_pixel(x, y), heading_from_yaw(yaw))``;
- the occupancy is the rotated map (``WindowPose.occupancy``: an obstacle is never skipped, free space never
  invented, cells off the map unknown);
- the goal must lie ``margin_m`` inside the window, as in every training instance. A goal farther away is a
  failure (``far_goal="fail"``) or, with ``far_goal="clip"``, replaced by the farthest free point towards it
  that fits (a sub-goal: plan again from nearer the goal).

A path found in the window is mapped back to map-frame metres (``WindowPose.to_map`` then ``pixel_to_world``).
What plans in the window is a subclass: :class:`spade.deploy.student_planner.Planner` (a student) or
:class:`spade.closedloop.planners.BaselinePlanner` (a classical predictor).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Union

import numpy as np

from spade.deploy.plan_result import PlannerConfigError, PlanResult, failed_plan
from spade.maps.frame import RobotFrame, WindowPose, heading_from_yaw
from spade.maps.occupancy import FREE, OCCUPIED, OccupancyMap
from spade.maps.ros_io import load_ros_map

__all__ = ["DEFAULT_MARGIN_M", "MapLike", "PlanWindow", "WindowPlanner", "goal_point", "robot_pose"]

MapLike = Union[OccupancyMap, str, Path]

DEFAULT_MARGIN_M = 0.3
"""The annotation tool's ``window.margin_m`` (conf/annotate.yaml): what a model file that does not record it was
trained on."""


@dataclass(frozen=True)
class PlanWindow:
    """The student's robot-frame window in a map at the student's resolution."""

    map: OccupancyMap
    pose: WindowPose

    @property
    def size(self) -> int:
        return self.pose.frame.size

    def to_window(self, xy_m: np.ndarray) -> np.ndarray:
        """Map-frame metres (..., 2) -> window pixel coordinates (..., 2) (x = column, y = row)."""
        return self.pose.to_window(self.map.world_to_pixel(np.asarray(xy_m, dtype=np.float64)))

    def to_world(self, px: np.ndarray) -> np.ndarray:
        """Window pixel coordinates (..., 2) -> map-frame metres (..., 2)."""
        return self.map.pixel_to_world(self.pose.to_map(np.asarray(px, dtype=np.float64)))

    def occupancy(self) -> np.ndarray:
        """(S, S) uint8 codes of the window (the training windows' conservative rotation)."""
        return self.pose.occupancy(self.map.grid)

    @property
    def corners_m(self) -> np.ndarray:
        """(4, 2) map-frame metres of the window's outer corners: top-left, top-right, bottom-right, bottom-left
        in the window (its top edge lies ahead of the robot)."""
        e = self.size - 0.5
        return self.to_world(np.array([[-0.5, -0.5], [e, -0.5], [e, e], [-0.5, e]]))

    @property
    def bounds_m(self) -> tuple[float, float, float, float]:
        """(x_min, y_min, x_max, y_max) of the (rotated) window's corners in map-frame metres."""
        c = self.corners_m
        return float(c[:, 0].min()), float(c[:, 1].min()), float(c[:, 0].max()), float(c[:, 1].max())



def robot_pose(value: Any, name: str = "start") -> np.ndarray:
    """(x, y, yaw) as float64; a bare (x, y) is refused: the window is in the robot's frame."""
    arr = np.asarray(value, dtype=np.float64).reshape(-1)
    if arr.shape == (2,):
        raise ValueError(
            f"{name}=({arr[0]:g}, {arr[1]:g}) is a position (x, y); the planner needs the robot's pose (x, y, yaw): "
            "the student sees the map in the robot's frame, rotated with its heading. Pass (x, y, yaw) in map-frame "
            "metres and radians (ROS yaw: counter-clockwise from the map's +x axis), e.g. start=X,Y,YAW on the "
            "command line"
        )
    if arr.shape != (3,) or not np.isfinite(arr).all():
        raise ValueError(f"{name} must be a robot pose (x, y, yaw) in map-frame metres and radians, got {value!r}")
    return arr


def goal_point(value: Any, name: str = "goal") -> np.ndarray:
    """(x, y) as float64 (a pose's yaw, if given, is not used: the student knows no goal heading)."""
    arr = np.asarray(value, dtype=np.float64).reshape(-1)
    if arr.shape not in ((2,), (3,)) or not np.isfinite(arr).all():
        raise ValueError(f"{name} must be (x, y) in map-frame metres, got {value!r}")
    return arr[:2].copy()



class WindowPlanner:
    """What every planner of robot-frame windows shares, with or without a network: a query (map, robot pose,
    goal) checked and turned into the window at ``resolution`` (:meth:`window`), the goal placed in it or clipped
    (``far_goal``), failures as :class:`PlanResult`. :class:`spade.deploy.student_planner.Planner` plans in the
    window with a student; :class:`spade.closedloop.planners.BaselinePlanner` with a classical predictor, on
    exactly the same windows.
    Subclasses implement :meth:`plan_windows`."""

    def __init__(self, frame: RobotFrame, resolution: float, *, margin_m: float = DEFAULT_MARGIN_M,
                 far_goal: str = "fail", num_waypoints: int = 64) -> None:
        if num_waypoints < 2:
            raise PlannerConfigError(f"num_waypoints must be >= 2, got {num_waypoints}")
        if far_goal not in ("fail", "clip"):
            raise PlannerConfigError(f"far_goal must be 'fail' or 'clip', got {far_goal!r}")
        self.frame = frame
        self.image_size = (frame.size, frame.size)
        self.resolution = float(resolution)
        self.margin_m = float(margin_m)
        self.far_goal = far_goal
        self.num_waypoints = int(num_waypoints)
        self._cache: tuple[OccupancyMap, OccupancyMap] | None = None  # (map given, map at the window's resolution)

    @property
    def margin_px(self) -> float:
        return self.margin_m / self.resolution

    # -- queries ---------------------------------------------------------------------------------------------
    def plan(self, map: MapLike, pose: Any, goal: Any, previous: np.ndarray | None = None) -> PlanResult:
        """Plan from the robot ``pose`` (x, y, yaw) to ``goal`` (x, y), both in map-frame metres, on ``map``.

        ``map``: an :class:`OccupancyMap` (a whole map, or a local one such as a rolling costmap converted to
        codes, with its origin in the map frame; cells of the window off it are unknown) or a ROS map yaml path.
        ``previous``: the waypoints (K, 2, map metres) of this robot's last plan to this goal, when it replans
        (the node, the Nav2 action, the closed loop pass it): the decoder keeps to its turn while the network
        still finds it plausible (:attr:`spade.deploy.student_planner.Planner.replan_prior`); None plans afresh.
        """
        return self.plan_batch(map, [pose], [goal], None if previous is None else [previous])[0]

    def plan_batch(self, maps: MapLike | Sequence[MapLike], poses: Any, goals: Any,
                   previous: Sequence[np.ndarray | None] | None = None) -> list[PlanResult]:
        """:meth:`plan` for N queries at once (a student: one pass of the network): ``maps`` one map for all or
        one per query, ``poses`` (N, 3) robot poses and ``goals`` (N, 2) in map-frame metres; ``previous`` None
        or one previous plan (or None) per query."""
        poses = [robot_pose(p) for p in poses]
        goals = [goal_point(g) for g in goals]
        if len(poses) != len(goals):
            raise ValueError(f"plan_batch got {len(poses)} poses and {len(goals)} goals; give one goal per pose")
        previous = [None] * len(poses) if previous is None else list(previous)
        if len(previous) != len(poses):
            raise ValueError(f"plan_batch got {len(previous)} previous plans for {len(poses)} queries; give one "
                             "(or None) per query, or previous=None")
        if isinstance(maps, (OccupancyMap, str, Path)):
            maps = [maps] * len(poses)
        maps = list(maps)
        if len(maps) != len(poses):
            raise ValueError(f"plan_batch got {len(maps)} maps for {len(poses)} queries; give one map or one each")
        loaded: dict[int, OccupancyMap] = {}
        results: list[PlanResult | None] = []
        pending: list[tuple[int, PlanWindow, np.ndarray, np.ndarray, bool]] = []
        for i, (m, pose, goal) in enumerate(zip(maps, poses, goals)):
            key = id(m)
            if key not in loaded:
                loaded[key] = m if isinstance(m, OccupancyMap) else load_ros_map(m)
            prepared = self._prepare(loaded[key], pose, goal)
            if isinstance(prepared, PlanResult):
                results.append(prepared)
                continue
            window, goal_px, goal_m, subgoal = prepared
            results.append(None)
            pending.append((i, window, goal_px, goal_m, subgoal))
        if pending:
            priors = [self.previous_in_window(w, poses[i], previous[i]) for i, w, *_ in pending]
            planned = self.plan_windows([(w, poses[i], g_px, g_m, sub) for i, w, g_px, g_m, sub in pending],
                                        priors if any(p is not None for p in priors) else None)
            for (i, *_), result in zip(pending, planned):
                results[i] = result
        return results  # type: ignore[return-value]

    def plan_windows(self, queries: list[tuple[PlanWindow, np.ndarray, np.ndarray, np.ndarray, bool]],
                     priors: Sequence[np.ndarray | None] | None = None) -> list[PlanResult]:
        """Plan in prepared windows: one (window, pose, goal window pixel, goal metres, sub-goal) per query;
        ``priors``: None, or per query the previous plan in its window's pixels (:meth:`previous_in_window`)."""
        raise NotImplementedError

    @staticmethod
    def previous_in_window(window: PlanWindow, pose: np.ndarray, previous: Any) -> np.ndarray | None:
        """A previous plan (K, 2, map metres) as the replanning prior of a query: its part from its point nearest
        the robot on (what is behind the robot is driven), in ``window``'s pixels; None for none or fewer than
        two finite points."""
        if previous is None:
            return None
        pts = np.asarray(previous, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 2 or not np.isfinite(pts).all():
            return None
        nearest = int(np.argmin(np.linalg.norm(pts - np.asarray(pose, np.float64)[:2], axis=1)))
        ahead = pts[nearest:]
        return window.to_window(ahead) if len(ahead) >= 2 else None

    # -- windows ---------------------------------------------------------------------------------------------
    def window(self, m: OccupancyMap, pose: Any) -> PlanWindow:
        """The student's window for a robot ``pose`` (x, y, yaw) in map metres on ``m`` (any resolution)."""
        pose = robot_pose(pose)
        coarse = self._at_resolution(m)
        return PlanWindow(coarse, self.frame.place(coarse.world_to_pixel(pose[:2]), heading_from_yaw(pose[2])))

    def _at_resolution(self, m: OccupancyMap) -> OccupancyMap:
        if abs(m.resolution - self.resolution) <= 1e-9 * self.resolution:
            return m
        if self._cache is not None and self._cache[0] is m:
            return self._cache[1]
        resampled = m.resampled(self.resolution)
        self._cache = (m, resampled)
        return resampled

    def _check_endpoint(self, m: OccupancyMap, xy: np.ndarray, name: str) -> PlanResult | None:
        col, row = np.rint(m.world_to_pixel(xy)).astype(np.int64)
        if not (0 <= row < m.height and 0 <= col < m.width):
            x0, y0 = m.origin[0], m.origin[1]
            wm, hm = m.size_m
            return failed_plan(f"{name}_outside_map", f"{name} ({xy[0]:.2f}, {xy[1]:.2f}) m lies outside map {m.name!r}, "
                            f"which spans x {x0:.2f}..{x0 + wm:.2f} m, y {y0:.2f}..{y0 + hm:.2f} m")
        code = int(m.grid[row, col])
        if code != FREE:
            what = "an obstacle" if code == OCCUPIED else "unknown space"
            return failed_plan(f"{name}_not_free", f"{name} ({xy[0]:.2f}, {xy[1]:.2f}) m lies in {what} (cell col {col}, "
                            f"row {row} of map {m.name!r}); give a {name} on a free cell")
        return None

    def _prepare(self, given: OccupancyMap, pose: np.ndarray, goal: np.ndarray
                 ) -> PlanResult | tuple[PlanWindow, np.ndarray, np.ndarray, bool]:
        for xy, name in ((pose[:2], "start"), (goal, "goal")):
            failed = self._check_endpoint(given, xy, name)
            if failed is not None:
                failed.pose, failed.start, failed.goal = pose, pose[:2].copy(), goal
                return failed
        window = self.window(given, pose)
        goal_px = window.to_window(goal)
        if self.frame.inside(goal_px[None], self.margin_px):
            return window, goal_px, goal, False
        if self.far_goal == "clip":
            clipped = self._clip_goal(window, goal)
            if clipped is not None:
                return window, window.to_window(clipped), clipped, True
        s, r = self.frame.size, np.asarray(self.frame.robot_px)
        ahead, side = (r[1] - goal_px[1]) * self.resolution, (goal_px[0] - r[0]) * self.resolution
        reach_ahead = (r[1] - self.margin_px) * self.resolution
        reach_behind = (s - 1 - self.margin_px - r[1]) * self.resolution
        reach_side = (min(r[0], s - 1 - r[0]) - self.margin_px) * self.resolution
        return failed_plan(
            "goal_too_far",
            f"the goal lies {abs(ahead):.2f} m {'ahead of' if ahead >= 0 else 'behind'} the robot and "
            f"{abs(side):.2f} m to its {'right' if side >= 0 else 'left'}; the student's window "
            f"reaches {reach_ahead:.2f} m ahead, {reach_behind:.2f} m behind and {reach_side:.2f} m to each side "
            f"(goal {self.margin_m} m inside it). Give a nearer goal (a waypoint of a global plan), turn the robot "
            "towards it, or use far_goal='clip'",
            pose=pose, start=pose[:2].copy(), goal=goal, window=window,
        )

    def _clip_goal(self, window: PlanWindow, goal: np.ndarray) -> np.ndarray | None:
        """The farthest free cell on the segment robot -> goal that lies ``margin_m`` inside the window (metres)."""
        m, pose = window.map, window.pose
        start_px = pose.robot
        goal_px = m.world_to_pixel(goal)
        direction = goal_px - start_px
        length = float(np.linalg.norm(direction))
        if length == 0:
            return None
        unit = direction / length
        min_dist = 2.0 * self.margin_px
        for dist in np.arange(min(length, math.hypot(*self.image_size)), min_dist, -0.5):
            cand = start_px + unit * dist
            if not self.frame.inside(pose.to_window(cand)[None], self.margin_px):
                continue
            col, row = np.rint(cand).astype(np.int64)
            if 0 <= row < m.height and 0 <= col < m.width and m.grid[row, col] == FREE:
                return m.pixel_to_world(cand)
        return None
