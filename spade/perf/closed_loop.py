"""Closed-loop evaluation throughput: scenarios per second on this machine, and where the time goes.

A trained student drives a scenario set (:mod:`spade.closedloop`) once; the planner's network
(:meth:`spade.planner.Planner.predict`) and its decoding (the search decoder, ``Planner._extract``) are timed
where they run, the rest of the loop (window preparation, following, collision checks, bookkeeping) is the
remainder. The baselines are timed as whole drives.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any
from spade.closedloop.planners import BaselinePlanner
from spade.closedloop.scenario_loading import load_scenarios
from spade.closedloop.simulate import ClosedLoopSettings, drive
from spade.deploy.student_planner import Planner
from spade.utils.timing import clocked

__all__ = ["closed_loop_costs"]


def closed_loop_costs(ckpt: str | Path, dataset: str | Path, scenarios: int | None = None,
                      baselines: tuple[str, ...] = ("shortest", "heading")) -> dict[str, Any]:
    """Drive ``scenarios`` (None: all) of the scenario set ``dataset`` with the student ``ckpt`` and the
    baselines; returns seconds per part, scenarios per second and plans per second."""
    from spade.data.path_dataset import PathDataset
    t0 = time.perf_counter()
    ds = PathDataset(dataset)
    scen = load_scenarios(ds, limit=scenarios)
    loading = time.perf_counter() - t0
    planner = Planner(ckpt, far_goal="clip")
    spent = {"network": 0.0, "decoding": 0.0}
    planner.predict = clocked(spent, "network", planner.predict)  # type: ignore[method-assign]
    planner._extract = clocked(spent, "decoding", planner._extract)  # type: ignore[method-assign]
    settings = ClosedLoopSettings()
    start = time.perf_counter()
    episodes = drive(planner, scen, settings)
    total = time.perf_counter() - start
    plans = sum(len(e.plans) for e in episodes)
    steps = sum(e.steps for e in episodes)
    out: dict[str, Any] = {
        "ckpt": str(ckpt), "dataset": str(dataset), "scenarios": len(scen), "plans": plans, "control_steps": steps,
        "loading_s": round(loading, 2), "student_s": round(total, 2),
        "network_s": round(spent["network"], 2), "decoding_s": round(spent["decoding"], 2),
        "rest_s": round(total - spent["network"] - spent["decoding"], 2),
        "scenarios_per_s": round(len(scen) / total, 2), "plans_per_s": round(plans / total, 1),
        "success_rate": round(sum(e.success for e in episodes) / max(len(episodes), 1), 3),
    }
    for kind in baselines:
        start = time.perf_counter()
        drive(BaselinePlanner(kind, planner.frame, planner.resolution, margin_m=planner.margin_m, far_goal="clip"),
              scen, settings)
        out[f"{kind}_s"] = round(time.perf_counter() - start, 2)
    out["all_s"] = round(out["student_s"] + sum(out[f"{k}_s"] for k in baselines), 2)
    return out
