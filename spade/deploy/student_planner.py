"""Plan with a trained student: a map, a robot pose and a goal in, waypoints in map metres out.

The student only ever saw the windows of the annotation tool, which are in the robot's frame
(:mod:`spade.maps.frame`): the robot at a fixed pixel, its heading up the image, the map rotated about it.
A query is turned into exactly such a window:

- the map is resampled to the student's resolution (``OccupancyMap.resampled``: obstacles never vanish);
- the robot pose (x, y, yaw) in map metres (ROS yaw: counter-clockwise from the map's +x axis) places the
  window: ``frame.place(world_to_pixel(x, y), heading_from_yaw(yaw))``, the frame being the one the model file
  records (``data.frame``; a model trained on the older axis-aligned windows is refused: retrain it);
- the occupancy is the rotated map (``WindowPose.occupancy``: an obstacle is never skipped, free space never
  invented, cells off the map unknown); the start disc is drawn at the robot's pixel and the goal disc at the
  goal's window pixel (``rasterize.render``, radius ``disc_radius_m``), as in the dataset's encoding
  (occupancy ``code * 0.5``, start, goal);
- the goal must lie ``margin_m`` inside the window, as in every training instance. A goal farther away is a
  failure (``far_goal="fail"``) or, with ``far_goal="clip"``, replaced by the farthest free point towards it
  that fits (a sub-goal: plan again from nearer the goal).

The path is decoded by search (``decode="search"``, the default; :class:`spade.metrics.decoding.PathDecoder`):
the minimum-cost path over ``-log p`` plus the window costmap's inflation from the robot's pixel to the goal's
centre, never through a non-free cell, smoothed with the annotation tool's smoother. It always reaches the goal
when a free path exists in the window, and carries its confidence (the share of its length through pixels with
``p < 0.5``, the lowest ``p`` along it); ``fallback="shortest"`` returns the Nav2-like shortest path, flagged,
when that share exceeds ``low_confidence_share``. ``decode="skeleton"`` keeps the paper's extraction
(:func:`spade.metrics.extract_path`: threshold, skeleton, longest chain from the start). The path is mapped back
to map-frame metres (``WindowPose.to_map`` then ``pixel_to_world``). Every way a query can fail gives a
:class:`PlanResult` with ``success=False``, a short ``code`` and a readable ``reason``, keeping whatever was
computed (window, probabilities) for debugging.

Replanning: a robot plans again as it drives, and a query may pass the robot's previous plan to the same goal
(``previous``, map metres: the node, the Nav2 action and the closed loop do). Its part ahead of the robot, in the
new window's pixels (:meth:`WindowPlanner.previous_in_window`), is the search decoder's prior (``replan_prior``,
:mod:`spade.metrics.decoding`): the plan keeps the turn it chose unless the network now finds that turn far
less likely than another or the map blocks it. ``replan_prior=0`` turns it off; a query without ``previous`` (a
single plan, ``spade.plan``) is decoded as before.

Model files: a checkpoint from ``python -m spade.train``, or its ONNX / TorchScript export
(``python -m spade.export``), opened by :func:`spade.models.modelfile.open_model` (one device policy). Where torch
is not installed (a deploy install, :mod:`spade.deploy.lean`) ONNX students are opened by
:mod:`spade.deploy.onnx_runtime` (onnxruntime alone) and importing this module imports no torch.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Union

import numpy as np

from spade.deploy.lean import LEAN, defer_package_inits

if LEAN:  # no torch here (a deploy install): the packages' torch-importing __init__s are not run
    defer_package_inits("spade.data", "spade.metrics", "spade.models")

from spade.data.rasterize import render  # noqa: E402 - after the deploy install's package set-up
from spade.maps import FREE, OCCUPIED, OccupancyMap, load_ros_map  # noqa: E402
from spade.maps.frame import RobotFrame, WindowPose, heading_from_yaw  # noqa: E402
from spade.metrics.extraction import ExtractedPath, extract_path  # noqa: E402
from spade.data.polyline import resample_polyline  # noqa: E402
from spade.metrics.decoding import DecodedPath, PathDecoder  # noqa: E402

if LEAN:  # ONNX students through onnxruntime alone
    from spade.deploy.onnx_runtime import ModelFileError, UnsafeModelFileError, open_model, robot_frame
else:
    from spade.models.modelfile import ModelFileError, UnsafeModelFileError, open_model, robot_frame

__all__ = ["PlanResult", "PlanWindow", "Planner", "PlannerConfigError", "WindowPlanner"]

MapLike = Union[OccupancyMap, str, Path]

# The annotation tool's defaults (conf/annotate.yaml): what a model file that does not record them was trained on.
DEFAULT_DISC_RADIUS_M = 0.1
DEFAULT_MARGIN_M = 0.3
DEFAULT_REPLAN_PRIOR = 0.9
"""``replan_prior``'s default: the share of ``-log p`` taken off on the previous plan when replanning (measured:
docs/results/records/replanning/; 0 turns the prior off)."""


class PlannerConfigError(ModelFileError):
    """A model file the planner cannot use as it is (wrong role, no robot frame, bad option)."""


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


@dataclass
class PlanResult:
    """The outcome of one query.

    ``waypoints``: (K, 2) float64 map-frame metres from the robot to the goal, evenly spaced by arc length; an
    empty (0, 2) array when ``success`` is False. ``code``: None on success, else one of ``start_outside_map``,
    ``start_not_free``, ``goal_outside_map``, ``goal_not_free``, ``goal_too_far``, ``no_free_path`` (no
    collision-free path joins robot and goal inside the window); with ``decode="skeleton"`` also ``empty`` (no
    pixel above the threshold), ``too_short``, ``start_not_reached`` (the path begins away from the robot),
    ``goal_not_reached``, ``collision``; ``reason`` says it in words. ``decode``: how the path was read from the
    probabilities (``search`` or ``skeleton``). ``low_share``: the share of the path's length through pixels the
    network gave ``p < 0.5``, ``min_probability`` the lowest ``p`` along it (search decoding; NaN otherwise);
    ``low_confidence``: ``low_share`` above the planner's ``low_confidence_share``; ``fallback``: the waypoints are
    the Nav2-like shortest path that ``fallback="shortest"`` put in place of a low-confidence plan. ``prior``:
    what became of the previous plan a replan was given (:attr:`spade.metrics.decoding.DecodedPath.prior`: None,
    ``used``, ``blocked``: it crossed a non-free cell and was abandoned, ``outside``). ``pose``: the
    robot pose (x, y, yaw) planned from; ``start`` its (x, y). ``goal``: the goal planned to (the sub-goal when
    ``far_goal="clip"`` moved it; then ``subgoal`` is True). ``window``: where the student's window lies
    (:class:`PlanWindow`). ``probability``: the (S, S) path probabilities of the window and ``state`` the
    (3, S, S) network input (None when the query failed before the network ran); ``pixels``: the waypoints in
    window pixel coordinates; ``extraction``: the raw :class:`~spade.metrics.ExtractedPath`; ``blocked``:
    waypoints and path pixels on non-free cells.
    """

    success: bool
    waypoints: np.ndarray
    code: str | None = None
    reason: str | None = None
    pose: np.ndarray | None = None
    start: np.ndarray | None = None
    goal: np.ndarray | None = None
    subgoal: bool = False
    window: PlanWindow | None = None
    state: np.ndarray | None = field(default=None, repr=False)
    probability: np.ndarray | None = field(default=None, repr=False)
    pixels: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)), repr=False)
    extraction: ExtractedPath | DecodedPath | None = field(default=None, repr=False)
    blocked: int = 0
    decode: str = "search"
    low_share: float = float("nan")
    min_probability: float = float("nan")
    low_confidence: bool = False
    fallback: bool = False
    prior: str | None = None

    def __bool__(self) -> bool:
        return self.success

    @property
    def length_m(self) -> float:
        """Length of the waypoint polyline in metres (0 on failure)."""
        if len(self.waypoints) < 2:
            return 0.0
        return float(np.linalg.norm(np.diff(self.waypoints, axis=0), axis=1).sum())


def _blocked(codes: np.ndarray, points: np.ndarray, start_px: np.ndarray, goal_px: np.ndarray) -> int:
    """Points of a window path on non-free cells, other than the robot's and the goal's own cells."""
    cells = np.rint(np.asarray(points, np.float64)).astype(np.int64)
    cells[:, 0] = np.clip(cells[:, 0], 0, codes.shape[1] - 1)
    cells[:, 1] = np.clip(cells[:, 1], 0, codes.shape[0] - 1)
    ends = {tuple(np.rint(start_px).astype(np.int64)), tuple(np.rint(goal_px).astype(np.int64))}
    return int(sum(codes[r, c] != FREE and (c, r) not in ends for c, r in cells))


def _failure(code: str, reason: str, **kwargs: Any) -> PlanResult:
    return PlanResult(success=False, waypoints=np.zeros((0, 2)), code=code, reason=reason, **kwargs)


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


def _sigmoid(x: np.ndarray) -> np.ndarray:
    return (0.5 * (1.0 + np.tanh(0.5 * x))).astype(np.float32)


class WindowPlanner:
    """What every planner of robot-frame windows shares, with or without a network: a query (map, robot pose,
    goal) checked and turned into the window at ``resolution`` (:meth:`window`), the goal placed in it or clipped
    (``far_goal``), failures as :class:`PlanResult`. :class:`Planner` plans in the window with a student;
    :class:`spade.closedloop.planners.BaselinePlanner` with a classical predictor, on exactly the same windows.
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
        still finds it plausible (:attr:`Planner.replan_prior`); None plans afresh.
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
            return _failure(f"{name}_outside_map", f"{name} ({xy[0]:.2f}, {xy[1]:.2f}) m lies outside map {m.name!r}, "
                            f"which spans x {x0:.2f}..{x0 + wm:.2f} m, y {y0:.2f}..{y0 + hm:.2f} m")
        code = int(m.grid[row, col])
        if code != FREE:
            what = "an obstacle" if code == OCCUPIED else "unknown space"
            return _failure(f"{name}_not_free", f"{name} ({xy[0]:.2f}, {xy[1]:.2f}) m lies in {what} (cell col {col}, "
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
        return _failure(
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

def describe_footprint(footprint: dict[str, Any] | None) -> str:
    """``robot radius 0.105 m + inflation 0.55 m`` (``assumed`` when the model file predates the record)."""
    if not footprint:
        return "robot footprint not recorded"
    return (f"trained for a robot radius {footprint['radius_m']:g} m + inflation {footprint['inflation_radius_m']:g} m"
            + (" (assumed: the model file predates footprint records)" if footprint.get("assumed") else ""))


def check_footprint(recorded: Any, radius_m: float | None, inflation_m: float | None, mismatch: str,
                    path: str | Path) -> dict[str, Any] | None:
    """The model's footprint (``data.footprint``), checked against the robot's when given: a robot radius or an
    inflation that differs is refused (PlannerConfigError) or, with ``mismatch="warn"``, warned about."""
    import warnings

    if mismatch not in ("refuse", "warn"):
        raise PlannerConfigError(f"footprint_mismatch must be 'refuse' or 'warn', got {mismatch!r}")
    footprint = None
    if isinstance(recorded, dict) and all(isinstance(recorded.get(k), (int, float)) and not isinstance(
            recorded.get(k), bool) for k in ("radius_m", "inflation_radius_m")):
        footprint = {"radius_m": float(recorded["radius_m"]), "inflation_radius_m": float(recorded["inflation_radius_m"])}
        if recorded.get("assumed"):
            footprint["assumed"] = True
    given = {"radius_m": radius_m, "inflation_radius_m": inflation_m}
    for key, value in given.items():
        if value is not None and (isinstance(value, bool) or not isinstance(value, (int, float))
                                  or not math.isfinite(float(value)) or float(value) < 0):
            name = "robot_radius_m" if key == "radius_m" else key
            raise PlannerConfigError(f"{name}={value!r}: a robot size in metres, >= 0 (or null: not checked)")
    asked = {k: float(v) for k, v in given.items() if v is not None}
    if not asked:
        return footprint
    if footprint is None:
        warnings.warn(f"{path}: the model file records no robot footprint, so the robot's (radius "
                      f"{asked.get('radius_m', '?')} m, inflation {asked.get('inflation_radius_m', '?')} m) cannot "
                      "be checked; export it again with this SPADE", UserWarning, stacklevel=3)
        return None
    differ = [k for k, v in asked.items() if abs(v - footprint[k]) > 1e-6]
    if not differ:
        return footprint
    names = {"radius_m": "robot_radius_m", "inflation_radius_m": "inflation_radius_m"}
    what = ", ".join(f"{names[k]} {asked[k]:g} m (the model's {footprint[k]:g} m)" for k in differ)
    message = (f"{path}: this robot differs from the one the model's demonstrations assumed: {what}. Its plans keep "
               "the trained robot's clearances; generate data for this robot (python -m spade.annotate "
               "robot.radius_m=... robot.inflation_radius_m=...; docs/how-to/own-map-footprint.md) and train on it, "
               "or pass footprint_mismatch=warn to plan anyway")
    if footprint.get("assumed"):
        message += " (the model file predates footprint records: its footprint is assumed, so this is only a warning)"
    if mismatch == "refuse" and not footprint.get("assumed"):
        raise PlannerConfigError(message)
    warnings.warn(message, UserWarning, stacklevel=3)
    return footprint


class Planner(WindowPlanner):
    """A trained student as a path planner (see the module docstring for how queries become windows).

    Args:
        model: a student checkpoint (``.ckpt``, from ``python -m spade.train``) or its export (``.onnx``, ``.pt``).
        device: ``cpu``, ``cuda[:N]`` or ``auto`` (:func:`spade.models.modelfile.resolve_device`).
        num_waypoints: points of the returned polyline.
        decode: ``search`` (default: the minimum-cost path over ``-log p`` on the window's costmap, robot to
            goal, :class:`~spade.metrics.decoding.PathDecoder`) or ``skeleton`` (the paper's extraction).
        fallback: None (default) or ``shortest``: a plan whose ``low_share`` exceeds ``low_confidence_share`` is
            replaced by the Nav2-like shortest path on the window's inflated costmap, flagged ``fallback=True``.
        low_confidence_share: the share of a decoded path's length through pixels with ``p < threshold`` above
            which the plan is flagged ``low_confidence`` (default 0.1).
        threshold, max_gap, goal_tolerance_px: :func:`spade.metrics.extract_path` options (the evaluation's);
            ``threshold`` is also the decoder's confidence threshold.
        disc_radius_m, margin_m: the annotation tool's ``instances.disc_radius_m`` and ``window.margin_m`` the
            student was trained with (defaults: conf/annotate.yaml's, unless the model file records them).
        far_goal: ``fail`` (default) or ``clip`` (plan to the farthest free point towards the goal that fits).
        require_goal: a path that does not reach the goal (within ``goal_tolerance_px``) is a failure.
        collision_check: a path over a non-free cell of the window (occupied or unknown) is a failure.
        batch_size: windows per forward pass in :meth:`plan_batch`.
        threads: onnxruntime intra-op threads for an ONNX model (None: its default).
        robot_radius_m, inflation_radius_m: the robot this planner drives (None: not checked). The model file
            records the footprint its demonstrations assumed (``data.footprint``, :attr:`footprint`); a robot that
            differs is refused, or only warned about with ``footprint_mismatch="warn"``.
        footprint_mismatch: ``refuse`` (default) or ``warn``.
        allow_unsigned: open an export that carries no integrity record (weight digest, parity probe, the digests
            of the fields above), with a warning, instead of refusing it (:mod:`spade.models.onnx_check`).
        replan_prior: the pull of a replan towards the robot's previous plan, in [0, 1) (search decoding): on the
            previous plan each pixel's ``-log p`` is scaled by ``1 - replan_prior`` (less farther from it), so a
            replan keeps the turn it chose while the network still finds it plausible, and changes it where the
            network gives it a ``-log p`` more than ``1 / (1 - replan_prior)`` times another way's, or where the map
            blocks it (:mod:`spade.metrics.decoding`, replanning). 0 turns it off: every replan decides afresh. Used
            only when a query passes ``previous`` (the node, the Nav2 action and the closed loop do; one plan has
            none).
    """

    def __init__(
        self,
        model: str | Path,
        *,
        device: str = "cpu",
        num_waypoints: int = 64,
        threshold: float = 0.5,
        max_gap: float = 2.0,
        goal_tolerance_px: float = 4.0,
        disc_radius_m: float | None = None,
        margin_m: float | None = None,
        far_goal: str = "fail",
        require_goal: bool = True,
        collision_check: bool = True,
        batch_size: int = 64,
        threads: int | None = None,
        decode: str = "search",
        fallback: str | None = None,
        low_confidence_share: float = 0.1,
        robot_radius_m: float | None = None,
        inflation_radius_m: float | None = None,
        footprint_mismatch: str = "refuse",
        allow_unsigned: bool = False,
        replan_prior: float = DEFAULT_REPLAN_PRIOR,
    ) -> None:
        path = Path(model).expanduser()
        if not path.is_file():
            raise FileNotFoundError(f"planner model {path} does not exist; pass a student checkpoint (.ckpt) from "
                                    "python -m spade.train or its export (.onnx / .pt) from python -m spade.export")
        self.path = path
        try:
            if not isinstance(allow_unsigned, bool):
                raise PlannerConfigError(f"allow_unsigned must be true or false, got {allow_unsigned!r}")
            self.backend = open_model(path, device, threads, role="student", allow_unsigned=allow_unsigned)
            frame = RobotFrame.from_json(robot_frame(self.backend.info, path))
        except UnsafeModelFileError:
            raise
        except ModelFileError as err:
            raise PlannerConfigError(str(err)) from None
        data = dict(self.backend.info["data"])
        size = [int(v) for v in data["image_size"]]
        if size != [frame.size, frame.size]:
            raise PlannerConfigError(f"{path}: image_size {size} disagrees with its robot frame's "
                                     f"{frame.size} px window; the file was not written by SPADE")
        resolution = float(data["resolution_m"])
        if not (math.isfinite(resolution) and resolution > 0):
            raise PlannerConfigError(f"{path}: resolution_m must be a positive number of metres per pixel, "
                                     f"got {data['resolution_m']!r}")
        self.disc_radius_m = float(disc_radius_m if disc_radius_m is not None
                                   else data.get("disc_radius_m", DEFAULT_DISC_RADIUS_M))
        from spade.data.encoding import MARKER_ENCODINGS

        self.marker_encoding = str(data.get("marker_encoding", "binary"))  # the model's own: never another one
        if self.marker_encoding not in MARKER_ENCODINGS:
            raise PlannerConfigError(f"{path}: marker_encoding {self.marker_encoding!r} is not one this SPADE draws "
                                     f"({list(MARKER_ENCODINGS)}); update SPADE or retrain the model")
        super().__init__(frame, resolution, far_goal=far_goal, num_waypoints=num_waypoints,
                         margin_m=float(margin_m if margin_m is not None else data.get("margin_m", DEFAULT_MARGIN_M)))
        if batch_size < 1:
            raise PlannerConfigError(f"batch_size must be >= 1, got {batch_size}")
        if decode not in ("search", "skeleton"):
            raise PlannerConfigError(f"decode must be 'search' (the planner's search decoder) or 'skeleton' (the "
                                     f"paper's extraction), got {decode!r}")
        if fallback not in (None, "none", "shortest"):
            raise PlannerConfigError(f"fallback must be null or 'shortest', got {fallback!r}")
        if LEAN and fallback == "shortest":
            raise PlannerConfigError("fallback='shortest' needs torch (spade.metrics.baselines), which this deploy "
                                     "install lacks; use fallback=null or install torch")
        if not 0.0 <= float(low_confidence_share) <= 1.0:
            raise PlannerConfigError(f"low_confidence_share must lie in [0, 1], got {low_confidence_share}")
        if (isinstance(replan_prior, bool) or not isinstance(replan_prior, (int, float))
                or not 0 <= float(replan_prior) < 1):
            raise PlannerConfigError(f"replan_prior={replan_prior!r}: a share in [0, 1), e.g. "
                                     f"replan_prior={DEFAULT_REPLAN_PRIOR:g} (0: every replan decides afresh)")
        self.decode = decode
        self.fallback = None if fallback in (None, "none") else fallback
        self.low_confidence_share = float(low_confidence_share)
        # The endpoints were checked free on the map; the window's conservative rotation may still mark the robot's
        # or the goal's own cell non-free (2 x 2 footprint), which must not make a feasible plan fail.
        self.decoder = PathDecoder(num_points=num_waypoints, threshold=threshold, force_endpoints=True,
                                   prior_weight=float(replan_prior))
        self.threshold, self.max_gap = float(threshold), float(max_gap)
        self.goal_tolerance_px = float(goal_tolerance_px)
        self.require_goal, self.collision_check = bool(require_goal), bool(collision_check)
        self.batch_size = int(batch_size)
        self.footprint = check_footprint(data.get("footprint"), robot_radius_m, inflation_radius_m,
                                         footprint_mismatch, path)

    @property
    def replan_prior(self) -> float:
        """The pull towards the previous plan when replanning, in [0, 1) (0: off); see the class docstring."""
        return self.decoder.prior_weight

    def __repr__(self) -> str:
        h, w = self.image_size
        return (f"Planner({self.path.name}, {h}x{w} px robot-frame windows at {self.resolution} m/px, "
                f"{describe_footprint(self.footprint)})")

    # -- network ---------------------------------------------------------------------------------------------
    def predict(self, states: np.ndarray) -> np.ndarray:
        """Path probabilities (N, H, W) of network inputs (N, 3, H, W), in chunks of ``batch_size``."""
        states = np.asarray(states, dtype=np.float32)
        if states.ndim != 4 or states.shape[1] != 3 or tuple(states.shape[2:]) != self.image_size:
            raise ValueError(f"states must be (N, 3, {self.image_size[0]}, {self.image_size[1]}), got {states.shape}")
        out = [self.backend.logits(states[i: i + self.batch_size]) for i in range(0, len(states), self.batch_size)]
        return _sigmoid(np.concatenate(out)[:, 0]) if out else np.zeros((0, *self.image_size), np.float32)

    def plan_windows(self, queries: list[tuple[PlanWindow, np.ndarray, np.ndarray, np.ndarray, bool]],
                     priors: Sequence[np.ndarray | None] | None = None) -> list[PlanResult]:
        """The student's plans in prepared windows: their states through the network in one pass, each decoded
        (towards its previous plan in ``priors``, when given)."""
        robot_px = np.asarray(self.frame.robot_px, dtype=np.float64)
        states = np.stack([self.encode(w.occupancy(), robot_px, g) for w, _, g, _, _ in queries])
        probs = self.predict(states)
        priors = [None] * len(queries) if priors is None else list(priors)
        return [self._extract(window, state, prob, pose, goal_px, goal_m, subgoal, prior)
                for (window, pose, goal_px, goal_m, subgoal), state, prob, prior in zip(queries, states, probs, priors)]

    # -- steps -----------------------------------------------------------------------------------------------
    def encode(self, occupancy: np.ndarray, start_px: np.ndarray, goal_px: np.ndarray) -> np.ndarray:
        """The (3, S, S) float32 network input of a window: occupancy code * 0.5, start and goal markers drawn with
        the model's ``marker_encoding`` (binary discs, or at their exact sub-pixel position)."""
        occupancy = np.asarray(occupancy, dtype=np.uint8)
        state = np.empty((3, *occupancy.shape), dtype=np.float32)
        np.multiply(occupancy, np.float32(0.5), out=state[0])
        if self.marker_encoding == "binary":
            # The annotation tool's own rasteriser draws the discs, so they are the training discs pixel for pixel.
            inst = render(occupancy, np.stack([start_px, goal_px]), self.disc_radius_m / self.resolution, 2)
            state[1] = inst.start
            state[2] = inst.goal
        else:
            from spade.data.encoding import marker_channels

            state[1:] = marker_channels(start_px, goal_px, occupancy.shape[0], self.disc_radius_m / self.resolution,
                                        self.marker_encoding)
        return state

    def _extract(self, window: PlanWindow, state: np.ndarray, prob: np.ndarray, pose: np.ndarray,
                 goal_px: np.ndarray, goal_m: np.ndarray, subgoal: bool, prior: np.ndarray | None = None
                 ) -> PlanResult:
        if self.decode == "search":
            return self._search(window, state, prob, pose, goal_px, goal_m, subgoal, prior)
        return self._skeleton(window, state, prob, pose, goal_px, goal_m, subgoal)

    def _search(self, window: PlanWindow, state: np.ndarray, prob: np.ndarray, pose: np.ndarray,
                goal_px: np.ndarray, goal_m: np.ndarray, subgoal: bool, prior: np.ndarray | None = None
                ) -> PlanResult:
        start_px = np.asarray(self.frame.robot_px, dtype=np.float64)
        codes = np.rint(state[0] * 2).astype(np.uint8)
        found = self.decoder(prob, codes, start_px, goal_px, self.resolution, prior=prior)
        common = dict(pose=pose, start=pose[:2].copy(), goal=np.asarray(goal_m, dtype=np.float64), subgoal=subgoal,
                      window=window, state=state, probability=prob, extraction=found, decode="search",
                      prior=found.prior)
        if not found.ok:
            what = {"start_blocked": "the robot's cell in the window is not free",
                    "goal_blocked": "the goal's cell in the window is not free"}.get(
                found.failure, "no collision-free path joins the robot and the goal inside the student's window")
            return _failure("no_free_path", f"no path: {what}", **common)
        low = found.low_confidence(self.low_confidence_share)
        result = dict(low_share=found.low_share, min_probability=found.min_prob, low_confidence=low,
                      blocked=_blocked(codes, found.points, start_px, goal_px))
        if low and self.fallback == "shortest":
            from spade.metrics.baselines import shortest_path  # imports torch: only for this fallback

            line = shortest_path(codes, start_px, goal_px, self.resolution)
            if line is not None:  # from the grid cells of the ends to the exact robot and goal positions
                points = resample_polyline(np.vstack([start_px, line[1:-1], goal_px]), self.num_waypoints)
                return PlanResult(success=True, waypoints=window.to_world(points), pixels=points, fallback=True,
                                  **result, **common)
        return PlanResult(success=True, waypoints=window.to_world(found.points), pixels=found.points, **result,
                          **common)

    def _skeleton(self, window: PlanWindow, state: np.ndarray, prob: np.ndarray, pose: np.ndarray,
                  goal_px: np.ndarray, goal_m: np.ndarray, subgoal: bool) -> PlanResult:
        start_px = np.asarray(self.frame.robot_px, dtype=np.float64)
        found = extract_path(prob, start_px, goal_px, self.num_waypoints, threshold=self.threshold,
                             max_gap=self.max_gap, goal_tolerance=self.goal_tolerance_px)
        common = dict(pose=pose, start=pose[:2].copy(), goal=np.asarray(goal_m, dtype=np.float64), subgoal=subgoal,
                      window=window, state=state, probability=prob, extraction=found, decode="skeleton")
        if not found.ok:
            why = {"empty": f"no pixel of the predicted path reaches probability {self.threshold}",
                   "too_short": "the predicted path near the start is a single pixel"}.get(found.failure, found.failure)
            return _failure(found.failure or "empty", f"no path extracted: {why}", **common)
        away = float(np.linalg.norm(found.points[0] - start_px))
        if away > self.goal_tolerance_px:  # the predicted path lies elsewhere: not a path the robot can drive
            return _failure("start_not_reached", f"the predicted path begins {away * self.resolution:.2f} m from the "
                            "robot", **common)
        if self.require_goal and not found.reached_goal:
            end = found.pixels[-1]
            gap = float(np.linalg.norm(end - goal_px)) * self.resolution
            return _failure("goal_not_reached", f"the predicted path stops {gap:.2f} m from the goal", **common)
        occupancy = state[0]
        cells = np.vstack([found.pixels, found.points])
        cols = np.clip(np.rint(cells[:, 0]).astype(np.int64), 0, occupancy.shape[1] - 1)
        rows = np.clip(np.rint(cells[:, 1]).astype(np.int64), 0, occupancy.shape[0] - 1)
        blocked = int((occupancy[rows, cols] != np.float32(FREE * 0.5)).sum())
        if self.collision_check and blocked:
            return _failure("collision", f"the predicted path crosses {blocked} non-free cells", blocked=blocked,
                            **common)
        return PlanResult(success=True, waypoints=window.to_world(found.points), pixels=found.points,
                          blocked=blocked, **common)
