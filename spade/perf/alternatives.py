"""The alternatives sampler measured: its cost, and what its prefilter loses against a looser one.

:mod:`spade.annotation.alternatives` draws by rejection on the executed path; to execute few templates it first
keeps those whose *ideal* curve passes near the robot (``prefilter_px``, ``prefilter_deg``). ``compare`` draws the
same robot states of a test set's scenarios with the shipped prefilter and with one ``looser`` times wider in both
(the reference: nearer to rejection without any prefilter) and reports, under each, the floor, the distance of the
demonstration to its nearest alternative, the spread, and the time taken.

``python -m spade.perf.alternatives dataset=DIR [scenarios=N] [states=N] [shape=L] [looser=2]`` prints the
comparison as JSON.
"""

from __future__ import annotations

import json
import sys
import time
from typing import Any

import numpy as np

from spade.annotation.alternatives import AlternativesSettings, scenario_alternatives
from spade.maps.frame import RobotFrame
from spade.metrics.preference import floor_path


def _figures(demo: np.ndarray, alts: np.ndarray, goal_centre: np.ndarray, cm: float) -> dict[str, float]:
    paths = np.concatenate([demo[None], alts]) if len(alts) else demo[None]
    floor = np.linalg.norm(floor_path(paths, goal_centre) - demo, axis=1).mean() * cm
    d = np.linalg.norm(alts - demo[None], axis=2).mean(axis=1) * cm if len(alts) else np.array([np.nan])
    return {"floor_cm": float(floor), "nearest_cm": float(d.min()), "spread_cm": float(np.median(d)),
            "count": int(len(alts))}


def compare(dataset: str, scenarios: int = 4, states: int = 6, shape: str = "L", count: int = 32,
            seed: int = 0, looser: float = 2.0) -> dict[str, Any]:
    """The shipped prefilter against one ``looser`` times wider, on ``states`` evenly spaced states of the first
    ``scenarios`` scenarios of ``shape`` in a template dataset (rebuilt from its manifest's generator record)."""
    from spade.annotation.pipeline import build_contexts
    from spade.annotation.scenarios import plan_scenario, state_indices_along
    from spade.annotation.sources import load_map_sources
    from spade.data.format import read_manifest
    from spade.data.rasterize import robot_instance
    from spade.metrics.extraction import marker_centre

    cfg = read_manifest(dataset).generator
    res = float(cfg["window"]["resolution_m"])
    contexts = build_contexts(load_map_sources(cfg["maps"], res), cfg)
    settings = AlternativesSettings.from_cfg({**dict(cfg.get("alternatives") or {}), "count": count})
    reference = AlternativesSettings.from_cfg({**settings.to_json(), "prefilter_px": looser * settings.prefilter_px,
                                               "prefilter_deg": looser * settings.prefilter_deg,
                                               "max_draws": int(looser * looser * settings.max_draws)})
    frame = RobotFrame.for_size(int(cfg["window"]["size_px"]))
    rows: list[dict[str, Any]] = []
    timing = {"sampler_s": 0.0, "reference_s": 0.0}
    rng = np.random.default_rng(seed)
    for index in range(scenarios):
        ctx = contexts[index % len(contexts)]
        result = plan_scenario(ctx, shape, index, cfg)
        if result.executed is None or result.sketch is None:
            continue
        pts, goal = result.executed.points, result.sketch[-1]
        all_states = state_indices_along(ctx, result.executed, cfg)
        picked = all_states[np.linspace(0, len(all_states) - 1, min(states, len(all_states))).astype(int)]
        t0 = time.perf_counter()
        sampled, _ = scenario_alternatives(ctx.costmap, shape, goal, pts, picked, cfg, settings, rng)
        timing["sampler_s"] += time.perf_counter() - t0
        t0 = time.perf_counter()
        exact, _ = scenario_alternatives(ctx.costmap, shape, goal, pts, picked, cfg, reference, rng)
        timing["reference_s"] += time.perf_counter() - t0
        for s in picked:
            inst = robot_instance(ctx.costmap.grid, pts[int(s):], frame, float(cfg["window"]["margin_m"]) / res,
                                  float(cfg["instances"]["disc_radius_m"]) / res, int(cfg["num_waypoints"]))
            if inst is None:
                continue
            demo = inst.waypoints.astype(np.float64)
            centre = marker_centre(inst.goal)
            rows.append({"scenario": result.scenario_id, "state": int(s),
                         "sampler": _figures(demo, sampled[int(s)], centre, res * 100),
                         "reference": _figures(demo, exact[int(s)], centre, res * 100)})
    summary = {}
    for key in ("floor_cm", "nearest_cm", "spread_cm", "count"):
        a = np.array([r["sampler"][key] for r in rows], float)
        b = np.array([r["reference"][key] for r in rows], float)
        ok = np.isfinite(a) & np.isfinite(b)
        summary[key] = {"sampler": float(a[ok].mean()), "reference": float(b[ok].mean()),
                        "ratio": float(a[ok].mean() / b[ok].mean()) if b[ok].mean() else float("nan")}
    return {"dataset": str(dataset), "shape": shape, "states": len(rows), "summary": summary, "timing": timing,
            "settings": settings.to_json(), "reference": reference.to_json(), "rows": rows}


def main(argv: list[str] | None = None) -> None:
    args = dict(a.split("=", 1) for a in (sys.argv[1:] if argv is None else argv))
    out = compare(args["dataset"], int(args.get("scenarios", 4)), int(args.get("states", 6)),
                  args.get("shape", "L"), int(args.get("count", 32)), looser=float(args.get("looser", 2.0)))
    out.pop("rows")
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
