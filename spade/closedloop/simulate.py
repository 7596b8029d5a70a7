"""Closed loop: a planner drives a robot through whole scenarios, replanning as the deployed node would.

For every scenario (:mod:`spade.closedloop.scenario_loading`) the robot starts at the demonstration's start pose
(moved by ``initial_offset`` when set) and drives toward its goal. It plans from its *believed* pose (the true pose plus
localisation noise, when set) with the planner, exactly as the ROS 2 node calls it; follows the plan with the
pure-pursuit follower (:mod:`spade.deploy.follower`); and plans again by the node's rule
(:func:`spade.ros.core.replan_trigger`: off the plan, near a sub-goal, or ``replan_every_m`` driven since the last
plan), passing the episode's previous plan as the node does (``previous``: the planner's ``replan_prior``). An
episode ends:

- ``success``: the robot's true position within ``goal_tolerance_m`` of the goal;
- ``collision``: its centre on a cell of the map's inflated costmap that is lethal for the robot (non-free, or closer
  to an obstacle than its radius: the check every demonstration passed when it was made);
- ``no_plan``: the planner failed with no plan to follow (the node stops the robot);
- ``timeout``: after ``budget_factor`` times the time the demonstration takes at the follower's speed, plus
  ``budget_extra_s``.

All episodes advance in lock-step so that the planner gets every query of one control step in one batch (one
pass of a student's network). Deterministic per ``seed``: each scenario's noise comes from its own generator,
seeded by the seed and the scenario's id.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from spade.deploy.follower import FollowerSettings, follow_step
from spade.closedloop.scenario_loading import Scenario
from spade.ros.core import CoreSettings, replan_trigger
from spade.annotation.scenarios import stable_hash

__all__ = ["OUTCOMES", "ClosedLoopSettings", "Episode", "PlanRecord", "drive", "replay"]

OUTCOMES = ("success", "collision", "no_plan", "timeout")


@dataclass(frozen=True)
class ClosedLoopSettings:
    """How the loop runs (see the module docstring). Distances in metres, angles in radians, times in seconds."""

    follower: FollowerSettings = field(default_factory=FollowerSettings)
    replan: CoreSettings = field(default_factory=lambda: CoreSettings(replan_every_m=0.5))
    goal_tolerance_m: float = 0.1
    budget_factor: float = 3.0
    budget_extra_s: float = 10.0
    noise_xy_m: float = 0.0
    noise_yaw_rad: float = 0.0
    initial_offset_m: float = 0.0
    initial_offset_rad: float = 0.0
    seed: int = 0

    def __post_init__(self) -> None:
        if not self.goal_tolerance_m > 0:
            raise ValueError(f"closed loop goal_tolerance_m must be > 0, got {self.goal_tolerance_m}")
        if not self.budget_factor > 0 or self.budget_extra_s < 0:
            raise ValueError("closed loop budget_factor must be > 0 and budget_extra_s >= 0, got "
                             f"{self.budget_factor} and {self.budget_extra_s}")
        for name in ("noise_xy_m", "noise_yaw_rad", "initial_offset_m", "initial_offset_rad"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"closed loop {name} must be a number >= 0, got {value!r}")


@dataclass
class PlanRecord:
    """One planning attempt: the believed pose it started from, the waypoints (metres; empty on failure), whether
    it ended at a sub-goal, its wall time, and why it ran."""

    pose: np.ndarray
    waypoints: np.ndarray
    subgoal: bool
    seconds: float
    trigger: str
    code: str | None = None
    step: int = 0  # the control step it was made at (simulated time: step * dt)
    prior: str | None = None  # what became of the previous plan (PlanResult.prior: None, used, blocked, outside)


@dataclass
class Episode:
    """One scenario driven: ``path`` (T, 3) the true poses from the start, ``outcome`` one of :data:`OUTCOMES`,
    ``plans`` every attempt in order, ``steps`` control steps."""

    scenario: Scenario
    path: np.ndarray
    outcome: str
    plans: list[PlanRecord]
    steps: int

    @property
    def success(self) -> bool:
        return self.outcome == "success"


def _lethal(scenario: Scenario, xy: np.ndarray) -> bool:
    col, row = np.rint(scenario.map.world_to_pixel(np.asarray(xy, np.float64))).astype(np.int64)
    cost = scenario.costmap.cost
    if not (0 <= row < cost.shape[0] and 0 <= col < cost.shape[1]):
        return True
    return not math.isfinite(float(cost[row, col]))


def _rng(seed: int, scenario: Scenario) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([int(seed) & 0xFFFFFFFF, stable_hash(scenario.scenario_id)]))


def _start_pose(scenario: Scenario, settings: ClosedLoopSettings, rng: np.random.Generator) -> np.ndarray:
    """The demonstration's start, moved sideways by ``initial_offset_m`` and turned by ``initial_offset_rad`` (each
    to a random side); an offset landing on a lethal cell is halved until it does not (up to 6 times)."""
    pose = np.asarray(scenario.start, np.float64).copy()
    if settings.initial_offset_m == 0 and settings.initial_offset_rad == 0:
        return pose
    side, turn = rng.choice([-1.0, 1.0]), rng.choice([-1.0, 1.0])
    normal = np.array([-math.sin(pose[2]), math.cos(pose[2])])
    for k in range(7):
        scale = 0.5 ** k
        moved = pose[:2] + side * settings.initial_offset_m * scale * normal
        if not _lethal(scenario, moved):
            return np.array([moved[0], moved[1], pose[2] + turn * settings.initial_offset_rad * scale])
    return np.array([pose[0], pose[1], pose[2] + turn * settings.initial_offset_rad])


@dataclass
class _Run:
    scenario: Scenario
    rng: np.random.Generator
    pose: np.ndarray
    budget_steps: int
    path: list[np.ndarray] = field(default_factory=list)
    plans: list[PlanRecord] = field(default_factory=list)
    plan: np.ndarray | None = None
    subgoal: bool = False
    tried_at: np.ndarray | None = None
    tried_time: float = -math.inf
    outcome: str | None = None
    steps: int = 0

    def believed(self, settings: ClosedLoopSettings) -> np.ndarray:
        if settings.noise_xy_m == 0 and settings.noise_yaw_rad == 0:
            return self.pose.copy()
        noise = self.rng.normal(size=3) * np.array([settings.noise_xy_m, settings.noise_xy_m, settings.noise_yaw_rad])
        return self.pose + noise


def _plan_batch(planner: Any, runs: list[_Run], poses: list[np.ndarray]) -> tuple[list[Any], float]:
    t0 = time.perf_counter()
    # each episode's last plan, as the node passes its own: the planner's replanning prior (replan_prior)
    results = planner.plan_batch([r.scenario.map for r in runs], poses, [r.scenario.goal for r in runs],
                                 previous=[r.plan for r in runs])
    return results, (time.perf_counter() - t0) / max(len(runs), 1)


def drive(planner: Any, scenarios: list[Scenario], settings: ClosedLoopSettings | None = None) -> list[Episode]:
    """Drive every scenario with ``planner`` (anything with the planner's ``plan_batch(maps, poses, goals,
    previous)``: a
    :class:`spade.planner.Planner`, a :class:`spade.closedloop.planners.BaselinePlanner`); one
    :class:`Episode` per scenario, in order."""
    s = settings or ClosedLoopSettings()
    f = s.follower
    runs = []
    for sc in scenarios:
        rng = _rng(s.seed, sc)
        seconds = s.budget_factor * sc.length_m / f.speed_mps + s.budget_extra_s
        pose = _start_pose(sc, s, rng)
        runs.append(_Run(sc, rng, pose, int(math.ceil(seconds / f.dt_s)), path=[pose.copy()]))
        if _lethal(sc, pose[:2]):
            runs[-1].outcome = "collision"
    while True:
        active = [r for r in runs if r.outcome is None]
        if not active:
            break
        for r in active:
            if np.linalg.norm(r.pose[:2] - r.scenario.goal) <= s.goal_tolerance_m:
                r.outcome = "success"
            elif r.steps >= r.budget_steps:
                r.outcome = "timeout"
        active = [r for r in active if r.outcome is None]
        beliefs = {id(r): r.believed(s) for r in active}
        asking, triggers = [], []
        for r in active:
            now = r.steps * f.dt_s
            if not r.plans:
                reason = "start"
            else:
                reason = replan_trigger(s.replan, beliefs[id(r)], r.plan, r.subgoal, r.tried_at, now - r.tried_time)
            if reason is not None:
                asking.append(r)
                triggers.append(reason)
        if asking:
            results, seconds = _plan_batch(planner, asking, [beliefs[id(r)] for r in asking])
            for r, reason, res in zip(asking, triggers, results):
                belief = beliefs[id(r)]
                r.tried_at, r.tried_time = belief.copy(), r.steps * f.dt_s
                waypoints = np.asarray(res.waypoints, np.float64) if res.success else np.zeros((0, 2))
                r.plans.append(PlanRecord(belief.copy(), waypoints, bool(res.subgoal), seconds, reason, res.code,
                                          r.steps, getattr(res, "prior", None)))
                r.plan, r.subgoal = (waypoints, bool(res.subgoal)) if res.success else (None, False)
                if r.plan is None:
                    r.outcome = "no_plan"
        for r in active:
            if r.outcome is not None:
                continue
            r.pose = follow_step(r.pose, r.plan, f, believed=beliefs[id(r)])
            r.steps += 1
            r.path.append(r.pose.copy())
            if _lethal(r.scenario, r.pose[:2]):
                r.outcome = "collision"
    return [Episode(r.scenario, np.stack(r.path), str(r.outcome), r.plans, r.steps) for r in runs]


def replay(scenarios: list[Scenario], settings: ClosedLoopSettings | None = None) -> list[Episode]:
    """The demonstration of every scenario driven exactly (no follower, no noise): the reference that the loop's
    checks and metrics must score as a success with no error. A demonstration that touches a lethal cell or ends
    away from its goal would show a scenario rebuilt wrongly."""
    s = settings or ClosedLoopSettings()
    out = []
    for sc in scenarios:
        demo = np.asarray(sc.demonstration, np.float64)
        heading = np.arctan2(np.diff(demo[:, 1], append=demo[-1, 1]), np.diff(demo[:, 0], append=demo[-1, 0]))
        heading[-1] = heading[-2] if len(heading) > 1 else sc.start[2]
        path = np.column_stack([demo, heading])
        hit = next((i for i, p in enumerate(demo) if _lethal(sc, p)), None)
        if hit is not None:
            outcome, path = "collision", path[: hit + 1]
        else:
            outcome = "success" if np.linalg.norm(demo[-1] - sc.goal) <= s.goal_tolerance_m else "timeout"
        plan = PlanRecord(sc.start.copy(), demo.copy(), False, 0.0, "start")
        out.append(Episode(sc, path, outcome, [plan], len(path) - 1))
    return out
