"""The alternatives sampler measured: its cost, and what its prefilter loses against a looser one.

:mod:`spade.annotation.alternative_demonstrations` draws by rejection on the executed path; to execute few templates it first
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
from pathlib import Path
from typing import Any

import numpy as np

from spade.annotation.alternative_demonstrations import (
    AlternativesSettings,
    TemplateDraws,
    execute_template as _execute,
    heading_window as _heading_window,
    in_heading_prior as _in_prior,
    remaining_path as _remaining,
    keypoints_pass,
    sample_templates,
    scenario_alternatives,
)
from spade.annotation.templates import SHAPES
from spade.maps.frame import RobotFrame, path_heading
from spade.metrics import catalog
from spade.metrics.preference import PreferenceMetrics, floor_path
from spade.annotation.pipeline import build_contexts
from spade.annotation.scenarios import plan_scenario, state_indices_along
from spade.annotation.sources import load_map_sources
from spade.data.format import read_manifest
from spade.data.path_dataset import PathDataset
from spade.data.rasterize import robot_instance
from spade.experiments.reporting.stats import paired
from spade.metrics.extraction import marker_centre
from spade.utils.provenance import command_line, provenance_lines, shown_path


def prefilter_capture(costmap: Any, shape: str, goal_px: np.ndarray, points: np.ndarray, state_indices: np.ndarray,
                      cfg: Any, settings: AlternativesSettings, reference: AlternativesSettings,
                      rng: np.random.Generator, rounds: int = 8) -> tuple[int, int]:
    """(kept, accepted): of the (template, state) pairs that ``reference``'s prefilter proposes and whose executed
    path passes the state (the definition), how many the shipped ``settings`` prefilter would have proposed too."""
    res = float(costmap.resolution)
    frame = RobotFrame.for_size(int(cfg["window"]["size_px"]))
    poses = np.stack([np.r_[points[i], path_heading(points, int(i))] for i in state_indices])
    wide = np.deg2rad(reference.prefilter_deg)
    window = _heading_window(poses, float(np.deg2rad(SHAPES[shape])), wide)
    kept = accepted = 0
    for _ in range(rounds):
        t = sample_templates(shape, cfg["template"], rng, reference.batch, theta_range=window)
        hit = keypoints_pass(t, goal_px, poses, res, reference.prefilter_px, wide, cfg["template"], shape)
        hit &= _in_prior(t.theta, cfg["template"])[:, None]
        for b in np.flatnonzero(hit.any(axis=1)):
            path = _execute(costmap, t, b, goal_px, cfg, shape, frame)
            if path is None:
                continue
            one = TemplateDraws(t.leg[b:b + 1], t.radius[b:b + 1], t.tail[b:b + 1], t.sign[b:b + 1],
                                t.theta[b:b + 1], t.turn)
            for j in range(len(poses)):
                if _remaining(path, poses[j], frame, 8, settings.pos_tol_px,
                              np.deg2rad(settings.heading_tol_deg)) is None:
                    continue
                accepted += 1
                kept += bool(keypoints_pass(one, goal_px, poses[j:j + 1], res, settings.prefilter_px,
                                            np.deg2rad(settings.prefilter_deg), cfg["template"], shape)[0, 0])
    return kept, accepted


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
    capture = [0, 0]
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
        kept, accepted = prefilter_capture(ctx.costmap, shape, goal, pts, picked, cfg, settings, reference, rng)
        capture[0] += kept
        capture[1] += accepted
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
        p = paired(a[ok].tolist(), b[ok].tolist())
        summary[key] = {"sampler": float(a[ok].mean()), "reference": float(b[ok].mean()),
                        "ratio": float(a[ok].mean() / b[ok].mean()) if b[ok].mean() else float("nan"),
                        "p": float("nan") if p is None else p}
    return {"dataset": str(dataset), "shape": shape, "states": len(rows), "summary": summary, "timing": timing,
            "capture": {"kept": capture[0], "accepted": capture[1]},
            "settings": settings.to_json(), "reference": reference.to_json(), "rows": rows}


def independent_floor(dataset: str, shape: str | None = None) -> dict[str, Any]:
    """The floor of a test set recomputed from its files alone (numpy on ``alternatives.bin``, ``waypoints.bin`` and
    ``goal.bin``, none of the metric's code): the pointwise median of each instance's demonstration and
    alternatives ended on its goal disc's centre (the metric's estimator) and, as a second estimator, the medoid of
    that set (the path of the set nearest to all others) ended the same way; both against the demonstration, in cm,
    beside what :class:`~spade.metrics.preference.PreferenceMetrics` computes from the same set."""
    import torch

    m = read_manifest(dataset)
    if not m.alternatives:
        raise ValueError(f"{dataset} has no alternative demonstrations (alternatives.count=0 when it was made)")
    n, k, a = m.num_instances, m.num_waypoints, m.alternatives
    root = Path(dataset)
    demos = np.fromfile(root / "waypoints.bin", dtype="<f4").reshape(n, k, 2).astype(np.float64)
    alts = np.fromfile(root / "alternatives.bin", dtype="<f4").reshape(n, a, k, 2).astype(np.float64)
    goal_bits = np.unpackbits(np.fromfile(root / "goal.bin", dtype=np.uint8).reshape(n, -1), axis=1
                              )[:, :m.height * m.width].reshape(n, m.height, m.width)
    shapes = np.array([m.label("shape", i) for i in range(n)])
    keep = [i for i in range(n) if (shape is None or shapes[i] == shape) and np.isfinite(alts[i]).all(axis=(1, 2)).any()]

    def resample(p: np.ndarray) -> np.ndarray:
        seg = np.linalg.norm(np.diff(p, axis=0), axis=1)
        u = np.concatenate([[0.0], np.cumsum(seg)])
        t = np.linspace(0.0, u[-1], k)
        return np.stack([np.interp(t, u, p[:, 0]), np.interp(t, u, p[:, 1])], axis=1)

    tol_cm = PreferenceMetrics().commit_tol_cm
    median_cm, medoid_cm, genuine = [], [], []
    ramp = np.linspace(0.0, 1.0, k)[:, None]
    for i in keep:
        paths = np.stack([resample(p) for p in [demos[i], *alts[i][np.isfinite(alts[i]).all(axis=(1, 2))]]])
        rows, cols = np.nonzero(goal_bits[i])
        centre = np.array([cols.mean(), rows.mean()])
        med = np.median(paths, axis=0)
        med = med + ramp * (centre - med[-1])
        pair = np.linalg.norm(paths[:, None] - paths[None], axis=3).mean(axis=2)
        medoid = paths[int(np.argmin(pair.sum(axis=1)))]
        if len(paths) >= 3:  # each alternative against the rest of its set: would a genuine draw commit?
            others = pair[1:].copy()
            others[np.arange(len(others)), np.arange(1, len(paths))] = np.inf
            genuine += list(others.min(axis=1) * m.resolution * 100.0 <= tol_cm)
        medoid = medoid + ramp * (centre - medoid[-1])
        cm = m.resolution * 100.0
        median_cm.append(np.linalg.norm(med - paths[0], axis=1).mean() * cm)
        medoid_cm.append(np.linalg.norm(medoid - paths[0], axis=1).mean() * cm)
    metric = PreferenceMetrics()
    ds = PathDataset(dataset)
    for start in range(0, len(keep), 64):
        items = [ds[i] for i in keep[start:start + 64]]
        metric.update([it["waypoints"].numpy() for it in items], torch.stack([it["state"] for it in items]),
                      torch.stack([it["waypoints"] for it in items]), torch.stack([it["alternatives"] for it in items]),
                      torch.tensor([it["resolution"] for it in items]))
    return {"dataset": str(dataset), "shape": shape, "instances": len(keep),
            "metric_floor_cm": float(metric.compute()["floor_cm"]),
            "independent_median_floor_cm": float(np.mean(median_cm)),
            "independent_medoid_floor_cm": float(np.mean(medoid_cm)),
            "commit_tol_cm": tol_cm, "genuine_commit_rate": float(np.mean(genuine)) if genuine else float("nan")}


def write_page(out_dir: str, comparison: dict[str, Any], floors: list[dict[str, Any]], seconds: float) -> Path:
    """``alternatives.md`` in ``out_dir``: the prefilter's loss and the floor checks, with their provenance."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    summ = comparison["summary"]
    rows = ["| figure (mean over states) | shipped prefilter | looser prefilter | ratio | paired t-test |",
            "|---|---:|---:|---:|---|"]
    for key, label in (("floor_cm", catalog.label("floor_cm")), ("nearest_cm", "demonstration to its nearest alternative (cm)"),
                       ("spread_cm", "median distance demonstration to alternatives (cm)"),
                       ("count", "alternatives drawn")):
        p = summ[key]["p"]
        test = "n/a" if p != p else f"p = {p:.3g}" + (", significant" if p < 0.05 else ", not significant")
        rows.append(f"| {label} | {summ[key]['sampler']:.3f} | {summ[key]['reference']:.3f} | "
                    f"{summ[key]['ratio']:.3f} | {test} |")
    frows = ["| test set | shape | instances | floor, the metric (cm) | independent: median (cm) | independent: "
             "medoid (cm) | metric / independent median | a genuine draw commits |", "|---|---|---:|---:|---:|---:|---:|---:|"]
    for f in floors:
        frows.append(f"| `{shown_path(f['dataset'])}` | {f['shape'] or 'all'} | {f['instances']} | "
                     f"{f['metric_floor_cm']:.3f} | {f['independent_median_floor_cm']:.3f} | "
                     f"{f['independent_medoid_floor_cm']:.3f} | "
                     f"{f['metric_floor_cm'] / f['independent_median_floor_cm']:.3f} | "
                     f"{100 * f['genuine_commit_rate']:.0f} % at {f['commit_tol_cm']:g} cm |")
    timing = comparison["timing"]
    text = "\n".join([
        "# Alternative demonstrations: the sampler checked",
        "",
        f"The sampler (`spade/annotation/alternative_demonstrations.py`) on {comparison['states']} robot states of "
        f"{comparison['shape']}-shape scenarios of `{shown_path(comparison['dataset'])}`, with the shipped prefilter "
        f"({comparison['settings']['prefilter_px']} px, {comparison['settings']['prefilter_deg']} deg) and with one "
        f"twice as loose ({comparison['reference']['prefilter_px']} px, {comparison['reference']['prefilter_deg']} "
        f"deg). Both keep a template only where its executed path passes the robot within "
        f"{comparison['settings']['pos_tol_px']} px and {comparison['settings']['heading_tol_deg']} deg; the looser "
        "one executes more candidates, so it loses fewer of the templates that pass. Time: "
        f"{timing['sampler_s']:.1f} s shipped, {timing['reference_s']:.1f} s looser. The two draw independently, so a "
        "state's figures differ by chance too: the paired t-test over the states says whether the means differ.",
        "",
        *rows,
        "",
        f"What the shipped prefilter loses, measured directly: of the {comparison['capture']['accepted']} "
        "(template, state) pairs that the looser prefilter proposed and whose executed path passes the state, the "
        f"shipped one would have proposed {comparison['capture']['kept']} "
        f"({100 * comparison['capture']['kept'] / max(1, comparison['capture']['accepted']):.1f} %).",
        "",
        "The floor of whole test sets, from the metric and recomputed from the files alone (numpy on "
        "`alternatives.bin`, `waypoints.bin`, `goal.bin`): the metric's estimator (pointwise median ended on the goal "
        "disc's centre) and a second one (the medoid of the set, ended the same way). The last column: the share of "
        "alternatives within the commitment tolerance of another path of their set (how often a path the generator "
        "drew counts as committed).",
        "",
        *frows,
        "",
        "Provenance:",
        "",
        *provenance_lines(command_line("spade.perf.alternatives")),
        f"- wall time: {seconds:.0f} s",
        "",
    ])
    page = out / "alternatives.md"
    page.write_text(text)
    return page


def main(argv: list[str] | None = None) -> None:
    """``dataset=DIR [scenarios=N] [states=N] [shape=L] [count=N] [looser=2] [floors=DIR,DIR] [output_dir=DIR]``."""
    args = dict(a.split("=", 1) for a in (sys.argv[1:] if argv is None else argv))
    t0 = time.perf_counter()
    out = compare(args["dataset"], int(args.get("scenarios", 4)), int(args.get("states", 6)),
                  args.get("shape", "L"), int(args.get("count", 32)), looser=float(args.get("looser", 2.0)))
    out.pop("rows")
    floors = [independent_floor(d, args.get("shape", "L")) for d in args.get("floors", args["dataset"]).split(",")]
    print(json.dumps({**out, "floors": floors}, indent=1))
    if args.get("output_dir"):
        print(f"results page: {write_page(args['output_dir'], out, floors, time.perf_counter() - t0)}")


if __name__ == "__main__":
    main()
