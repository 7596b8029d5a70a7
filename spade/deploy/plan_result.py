"""What a plan query returns (:class:`PlanResult`) and how a planner that cannot be used is refused
(:class:`PlannerConfigError`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from spade.deploy.lean import ModelFileError

if TYPE_CHECKING:
    from spade.deploy.robot_window import PlanWindow
    from spade.metrics.decoding import DecodedPath
    from spade.metrics.extraction import ExtractedPath

__all__ = ["PlanResult", "PlannerConfigError", "failed_plan"]


class PlannerConfigError(ModelFileError):
    """A model file the planner cannot use as it is (wrong role, no robot frame, bad option)."""


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
    window pixel coordinates; ``extraction``: the raw :class:`~spade.metrics.extraction.ExtractedPath`; ``blocked``:
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



def failed_plan(code: str, reason: str, **kwargs: Any) -> PlanResult:
    """A failed query's result: no waypoints, its ``code`` and ``reason``, and whatever was computed."""
    return PlanResult(success=False, waypoints=np.zeros((0, 2)), code=code, reason=reason, **kwargs)

