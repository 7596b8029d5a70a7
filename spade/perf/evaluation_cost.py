"""Where the time of one test pass and of one closed-loop drive goes (the training section of ``spade.bench``):
what to speed up in evaluating a student, beside the training step's own figures (:mod:`spade.perf.training`).

- :func:`one_test_pass_cost`: ``PathPlanningModule.test_step`` over a test set, then every metric's compute: the
  network (``predict_paths``), the planner's search decoder per instance (``PathMetrics.decode``), the model's
  metrics update (APE, Hd19, preference, the planner's figures, FID's features), the classical baselines and
  references scored beside it (their paths: the rest of ``test_step``; their metrics' update), the compute.
- :func:`one_drive_cost`: :func:`~spade.closedloop.simulate.drive` of a few scenarios by
  :class:`~spade.deploy.student_planner.Planner`: per query the network (``predict``), the decoder (``_extract``)
  and the windows (resampled, rotated, encoded: the rest of ``plan_batch``); the follower and collision checks (the
  drive minus its planning); the closed-loop metrics (``ClosedLoopMetrics`` update and compute).

Each part is clocked where it runs (:func:`spade.utils.timing.clocked`) during the one pass, after a warm-up call,
so the parts add up to the whole (``other``: what no part names). Weights are random (the cost does not depend on
their values); the windows are :mod:`spade.metrics.synthetic` L/U paths with their mirror image as alternative,
the scenarios L-shaped drives in a walled room.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from spade.closedloop.scenario_loading import DEFAULT_COST_WEIGHT, DEFAULT_ROBOT, Scenario
from spade.closedloop.simulate import ClosedLoopSettings, drive
from spade.data.polyline import resample_polyline
from spade.deploy.student_planner import Planner
from spade.maps.costmap import build_costmap
from spade.maps.occupancy import FREE, OCCUPIED, OccupancyMap
from spade.metrics.closed_loop import ClosedLoopMetrics
from spade.metrics.synthetic import synthetic_batch
from spade.models.modelfile import untrained_student
from spade.training.student_module import StudentModule
from spade.utils.timing import clocked

__all__ = ["one_drive_cost", "one_test_pass_cost", "room_scenarios"]


def _parts(spent: dict[str, float], total_s: float, per: int) -> list[dict[str, Any]]:
    """Rows (part, ms, ms per instance or scenario, share of the total), ``other`` (if any) and ``total`` last."""
    rest = total_s - sum(spent.values())
    spent = {**spent, "other": rest} if rest > 0 else spent
    rows = [{"part": k, "ms": 1e3 * s, "ms_each": 1e3 * s / per, "share": s / total_s} for k, s in spent.items()]
    return rows + [{"part": "total", "ms": 1e3 * total_s, "ms_each": 1e3 * total_s / per, "share": 1.0}]


def _test_batch(n: int, image_size: int, seed: int) -> dict[str, Any]:
    """``n`` synthetic instances in a test loader's layout, each with its mirror (across start-goal) as alternative."""
    d = synthetic_batch(n, size=image_size, num_points=64, seed=seed, width=2, resolution=6.4 / image_size)
    w = d["waypoints"]
    a, u = w[:, :1], (w[:, -1:] - w[:, :1]) / np.linalg.norm(w[:, -1:] - w[:, :1], axis=-1, keepdims=True)
    rel = w - a
    mirror = a + 2 * (rel * u).sum(-1, keepdims=True) * u - rel
    return {"state": torch.from_numpy(d["state"]), "path": torch.from_numpy(d["path"]),
            "waypoints": torch.from_numpy(w).float(), "alternatives": torch.from_numpy(mirror[:, None]).float(),
            "resolution": torch.from_numpy(d["resolution"]), "shape": ["L", "U"] * (n // 2) + ["L"] * (n % 2),
            "scenario_id": [f"synthetic/{i}" for i in range(n)]}


def one_test_pass_cost(size: str = "medium", image_size: int = 64, instances: int = 32, batch_size: int = 32,
                       seed: int = 0) -> dict[str, Any]:
    """One test pass of a fresh ``size`` student over ``instances`` synthetic ``image_size`` px windows in batches
    of ``batch_size``: ms per part, per instance and share (see the module docstring)."""
    if instances < 1 or batch_size < 1:
        raise ValueError(f"a test pass needs instances >= 1 and batch_size >= 1, got {instances} and {batch_size}")
    module = StudentModule(size=size).eval()
    data = _test_batch(instances, image_size, seed)

    def rows(a: int, b: int) -> dict[str, Any]:
        return {k: v[a:b] for k, v in data.items()}

    spent = dict.fromkeys(("network", "decoder", "update", "beside", "step"), 0.0)
    with torch.no_grad():
        module.on_test_epoch_start()
        module.test_step(rows(0, 2), 0)  # warm-up: first calls of the kernels, the decoder, the baselines
        module.on_test_epoch_start()
        module.test_metrics.reset()
        metrics = module.test_metrics
        module.predict_paths = clocked(spent, "network", module.predict_paths)  # type: ignore[method-assign]
        metrics.decode = clocked(spent, "decoder", metrics.decode)  # type: ignore[method-assign]
        metrics.update = clocked(spent, "update", metrics.update)  # type: ignore[method-assign]
        module.test_step = clocked(spent, "step", module.test_step)  # type: ignore[method-assign]
        beside = [*module._baseline_metrics.values(), *module._reference_metrics.values()]
        for m in beside:
            m.update = clocked(spent, "beside", m.update)
        t0 = time.perf_counter()
        for i, start in enumerate(range(0, instances, batch_size)):
            module.test_step(rows(start, start + batch_size), i)
        c0 = time.perf_counter()
        for m in [metrics, *beside]:
            m.compute()
        total = time.perf_counter() - t0
    parts = {"network (forward)": spent["network"], "search decoder": spent["decoder"],
             "metrics update (model)": spent["update"] - spent["decoder"],
             "baselines' and references' paths": spent["step"] - spent["update"] - spent["beside"] - spent["network"],
             "baselines' and references' metrics": spent["beside"],
             "metrics compute": total - (c0 - t0)}
    return {"student": size, "image_size": image_size, "instances": instances, "batch_size": batch_size,
            "rows": _parts(parts, total, instances)}


def room_scenarios(n: int, leg_m: float = 1.5) -> list[Any]:
    """``n`` L-shaped scenarios (a ``leg_m`` leg along +x, a left turn, a ``leg_m`` tail) in a walled 12 m room
    at 0.05 m/px, their starts on a 3 x 3 grid (repeated beyond 9, under their own ids)."""
    grid = np.full((240, 240), FREE, np.uint8)
    grid[[0, -1], :] = grid[:, [0, -1]] = OCCUPIED
    room = OccupancyMap(grid, 0.05, (0.0, 0.0, 0.0), "room")
    costmap = build_costmap(room.grid, room.resolution, DEFAULT_ROBOT, DEFAULT_COST_WEIGHT)
    out = []
    for k in range(n):
        x, y = 1.5 + 3.5 * (k % 3), 1.5 + 3.5 * (k // 3 % 3)
        demo = resample_polyline(np.array([[x, y], [x + leg_m, y], [x + leg_m, y + leg_m]]), 64)
        out.append(Scenario(f"room/L{k:03d}", "room", "L", room, costmap, np.array([x, y, 0.0]), demo[-1].copy(),
                            demo, np.zeros((0, 64, 2)), 0.6))
    return out


def one_drive_cost(size: str = "medium", scenarios: int = 4, image_size: int = 64,
                   resolution: float | None = None) -> dict[str, Any]:
    """One closed-loop drive of :func:`room_scenarios` by a fresh ``size`` student's planner on ``image_size`` px
    windows (``resolution`` m/px; None: a 6.4 m window): ms per part, per scenario and share, with the queries."""
    if scenarios < 1:
        raise ValueError(f"a drive needs scenarios >= 1, got {scenarios}")
    scen = room_scenarios(scenarios)
    with tempfile.TemporaryDirectory(prefix="spade_drive_cost_") as tmp:
        ckpt = Path(tmp) / "student.ckpt"
        torch.save(untrained_student(size, image_size, resolution or 6.4 / image_size), ckpt)
        planner = Planner(ckpt, far_goal="clip")
    planner.plan_batch([scen[0].map], [scen[0].start], [scen[0].goal])  # warm-up
    spent = dict.fromkeys(("network", "decoder", "planning"), 0.0)
    planner.predict = clocked(spent, "network", planner.predict)  # type: ignore[method-assign]
    planner._extract = clocked(spent, "decoder", planner._extract)  # type: ignore[method-assign]
    planner.plan_batch = clocked(spent, "planning", planner.plan_batch)  # type: ignore[method-assign]
    t0 = time.perf_counter()
    episodes = drive(planner, scen, ClosedLoopSettings())
    d0 = time.perf_counter()
    metrics = ClosedLoopMetrics()
    metrics.update(episodes)
    metrics.compute()
    total = time.perf_counter() - t0
    queries = sum(len(e.plans) for e in episodes)
    parts = {"network (forward)": spent["network"], "search decoder": spent["decoder"],
             "windows (resample, rotate, encode)": spent["planning"] - spent["network"] - spent["decoder"],
             "follower, collision checks, loop": (d0 - t0) - spent["planning"], "metrics": total - (d0 - t0)}
    rows = _parts(parts, total, scenarios)
    for row in rows[:3]:  # the planning parts, per query too
        row["ms_per_query"] = row["ms"] / max(queries, 1)
    return {"student": size, "image_size": image_size, "scenarios": scenarios, "queries": queries,
            "control_steps": sum(e.steps for e in episodes), "successes": sum(e.success for e in episodes),
            "query_ms": 1e3 * spent["planning"] / max(queries, 1), "rows": rows}
