"""The planners a student is driven against in closed loop, on the student's own windows.

:class:`BaselinePlanner` plans with a classical predictor of :mod:`spade.metrics.baselines` (the Nav2-like
shortest path on the window's inflated costmap, or the heading template) in exactly the window a student would
see (:class:`spade.deploy.student_planner.WindowPlanner`), so that it is replanned by the same rule, from the
same poses, under the same window limits. (The demonstration replayed, the reference, is :func:`spade.closedloop.simulate.replay`.)
"""

from __future__ import annotations

import numpy as np

from typing import Any

from spade.data.polyline import resample_polyline
from spade.deploy.plan_result import PlanResult
from spade.deploy.robot_window import DEFAULT_MARGIN_M, PlanWindow, WindowPlanner
from spade.maps.frame import RobotFrame

__all__ = ["BASELINE_PLANNERS", "BaselinePlanner", "DemonstrationPlanner"]

BASELINE_PLANNERS = ("shortest", "heading")
"""The classical planners driven in closed loop (the straight line is left out: it drives through walls)."""


class BaselinePlanner(WindowPlanner):
    """``kind``: ``shortest`` (Nav2-like: minimum cost on the window's inflated costmap) or ``heading`` (straight
    ahead, then a right angle to the goal)."""

    def __init__(self, kind: str, frame: RobotFrame, resolution: float, *, margin_m: float = DEFAULT_MARGIN_M,
                 far_goal: str = "clip", num_waypoints: int = 64) -> None:
        if kind not in BASELINE_PLANNERS:
            raise ValueError(f"unknown baseline planner {kind!r}; choose one of {list(BASELINE_PLANNERS)}")
        super().__init__(frame, resolution, margin_m=margin_m, far_goal=far_goal, num_waypoints=num_waypoints)
        self.kind = kind

    def __repr__(self) -> str:
        return f"BaselinePlanner({self.kind}, {self.frame.size} px windows at {self.resolution} m/px)"

    def plan_windows(self, queries: list[tuple[PlanWindow, np.ndarray, np.ndarray, np.ndarray, bool]],
                     priors: Any = None) -> list[PlanResult]:
        """The classical plans; ``priors`` (the previous plans) are not used: these planners decide the same way
        from every pose."""
        from spade.metrics.baselines import heading_template, shortest_path

        start = np.asarray(self.frame.robot_px, np.float64)
        out = []
        for window, pose, goal_px, goal_m, subgoal in queries:
            common = dict(pose=pose, start=pose[:2].copy(), goal=np.asarray(goal_m, np.float64), subgoal=subgoal,
                          window=window, decode=self.kind)
            if self.kind == "shortest":
                line = shortest_path(window.occupancy(), start, goal_px, self.resolution)
                if line is None:
                    out.append(PlanResult(False, np.zeros((0, 2)), code="no_free_path",
                                          reason="no collision-free path in the window", **common))
                    continue
                line = np.vstack([start, line[1:-1], goal_px]) if len(line) > 2 else np.stack([start, goal_px])
            else:
                line = heading_template(start, goal_px)
            points = resample_polyline(line, self.num_waypoints)
            out.append(PlanResult(True, window.to_world(points), pixels=points, **common))
        return out


class DemonstrationPlanner:
    """Plans each scenario's demonstration, from its point nearest the robot to its end: the demonstration
    *followed* by the same follower and replanning rule, so that what the follower itself costs (corners cut,
    tracking error) is on the page beside every planner. Queries are matched to scenarios by map and goal."""

    def __init__(self, scenarios: list[Any], num_waypoints: int = 64) -> None:
        self.num_waypoints = int(num_waypoints)
        self._demos = {self._key(s.map, s.goal): np.asarray(s.demonstration, np.float64) for s in scenarios}

    @staticmethod
    def _key(m: Any, goal: Any) -> tuple[int, float, float]:
        g = np.asarray(goal, np.float64)
        return id(m), round(float(g[0]), 6), round(float(g[1]), 6)

    def plan_batch(self, maps: list[Any], poses: list[Any], goals: list[Any], previous: Any = None
                   ) -> list[PlanResult]:
        """The demonstration from the robot on (``previous``, the last plans, is not needed: it is one path)."""
        out = []
        for m, pose, goal in zip(maps, poses, goals):
            demo = self._demos[self._key(m, goal)]
            pose = np.asarray(pose, np.float64)
            k = int(np.argmin(np.linalg.norm(demo - pose[:2], axis=1)))
            rest = np.vstack([pose[:2], demo[min(k + 1, len(demo) - 1):]])
            out.append(PlanResult(True, resample_polyline(rest, self.num_waypoints), pose=pose, start=pose[:2].copy(),
                                  goal=demo[-1].copy(), decode="demonstration"))
        return out
