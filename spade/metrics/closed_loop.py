"""Closed-loop metrics: how a planner drove whole scenarios (:mod:`spade.closedloop.simulate`), per episode and
over a test set, as Nav2's planner benchmarks and arena-evaluation judge planners.

Per episode (:func:`episode_figures`), in the map frame:

- the outcome: ``success``, ``collision``, ``no_plan`` (the planner failed with nothing to follow), ``timeout``;
- ``ape_cm``: the executed path (the robot's true positions, start to wherever it stopped) against the
  demonstration of the whole scenario, both resampled evenly by arc length to the demonstration's K points (the
  APE metric's convention): a failure's partial path scores what it missed;
- ``plausibility_cm`` / ``commit``: the same distance to the *nearest* path of the plausible set (the demonstration
  and its alternatives, :mod:`spade.metrics.preference`), and whether it is within ``commit_tol_cm`` of one (where
  the test set has alternatives);
- ``length_ratio``: executed length over the demonstration's (successful episodes);
- ``smoothness_deg_per_m``: mean absolute heading change per metre of the executed path (resampled every 5 cm);
- ``replan_change_cm``: between consecutive plans, the mean distance over their overlap (the earlier plan from
  the point nearest the later plan's start, both cut to the shorter length, resampled to K points): how much a
  replan moved the path still ahead;
- ``mode_switches``: how often the plan's way of turning changed between replans. A plan with at least
  ``min_turn_deg`` of turning left beyond its first 15 cm (where it joins the robot's pose) has a mode: its side (left or right) and its radius band (sharp or wide: the
  radius of its middle 80 % of turning, against the generator's boundary between the bands,
  ``Scenario.radius_boundary_m``);
- ``plan_ms``: wall time per planning query; ``replans``: queries per episode.

:class:`ClosedLoopMetrics` gathers episodes (``cat`` states, so the figures are right under DDP) and computes
rates and means.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import torch
from torchmetrics import Metric

from spade.data.polyline import polyline_length, resample_polyline
from spade.metrics._inputs import append_state, cat_state

__all__ = ["CLOSED_LOOP_KEYS", "ClosedLoopMetrics", "episode_figures", "plan_mode"]

FIGURES = ("success", "collision", "no_plan", "timeout", "ape_cm", "plausibility_cm", "commit", "length_ratio",
           "smoothness_deg_per_m", "replan_change_cm", "mode_switches", "plan_ms", "replans")

CLOSED_LOOP_KEYS: tuple[str, ...] = (
    "success_rate", "collision_rate", "no_plan_rate", "timeout_rate", "ape_cm", "plausibility_cm", "commit_rate",
    "length_ratio", "smoothness_deg_per_m", "replan_change_cm", "mode_switches", "plan_ms", "replans", "episodes")
"""What :class:`ClosedLoopMetrics` computes, logged as ``closed_loop/<key>`` (a baseline's with its prefix)."""

SPACING_M = 0.05  # the executed path's resampling for headings
JOIN_M = 0.15  # a plan's first stretch, where it joins the robot's pose (a kink after corner-cutting), has no mode


def _beyond(points: np.ndarray, distance_m: float) -> np.ndarray:
    """The part of a path beyond its first ``distance_m`` of length."""
    pts = np.asarray(points, np.float64)
    along = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
    return pts[along >= distance_m]


def _headings(points: np.ndarray) -> tuple[np.ndarray, float]:
    """Unwrapped headings of ``points`` resampled every :data:`SPACING_M`, and the path's length."""
    pts = np.asarray(points, np.float64)
    length = polyline_length(pts) if len(pts) > 1 else 0.0
    if length < 2 * SPACING_M:
        return np.zeros(0), length
    dense = resample_polyline(pts, int(length / SPACING_M) + 1)
    d = np.diff(dense, axis=0)
    return np.unwrap(np.arctan2(d[:, 1], d[:, 0])), length


def smoothness(points: np.ndarray) -> float:
    """Mean absolute heading change per metre (degrees / m) of a path in metres; NaN under 10 cm."""
    heading, length = _headings(points)
    if len(heading) < 2:
        return float("nan")
    return float(np.degrees(np.abs(np.diff(heading)).sum()) / length)


def plan_mode(points: np.ndarray, radius_boundary_m: float | None, min_turn_deg: float = 45.0
              ) -> tuple[int, int] | None:
    """(side, band) of a plan in metres: side +1 left / -1 right, band 0 sharp / 1 wide (-1 when the boundary is
    unknown); None when it turns less than ``min_turn_deg``."""
    heading, _ = _headings(points)
    if len(heading) < 3:
        return None
    turn = heading - heading[0]
    total = float(turn[-1])
    if abs(math.degrees(total)) < min_turn_deg:
        return None
    side = 1 if total > 0 else -1
    if radius_boundary_m is None:
        return side, -1
    progress = turn / total
    i10 = int(np.argmax(progress >= 0.1))
    i90 = int(np.argmax(progress >= 0.9))
    radius = max(i90 - i10, 1) * SPACING_M / (0.8 * abs(total))
    return side, int(radius > radius_boundary_m)


def _overlap_change(earlier: np.ndarray, later: np.ndarray, k: int) -> float:
    """Mean distance (metres) between two plans over their overlap (module docstring)."""
    a, b = np.asarray(earlier, np.float64), np.asarray(later, np.float64)
    nearest = int(np.argmin(np.linalg.norm(a - b[0], axis=1)))
    a = a[nearest:]
    if len(a) < 2 or len(b) < 2:
        return float("nan")
    length = min(polyline_length(a), polyline_length(b))
    if length <= 0:
        return float("nan")

    def cut(p: np.ndarray) -> np.ndarray:
        dense = resample_polyline(p, max(k, int(polyline_length(p) / 0.01) + 1))
        along = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(dense, axis=0), axis=1))])
        return resample_polyline(dense[: max(2, int(np.searchsorted(along, length, side="right")))], k)

    return float(np.linalg.norm(cut(a) - cut(b), axis=1).mean())


def episode_figures(episode: Any, commit_tol_cm: float = 1.5, min_turn_deg: float = 45.0) -> dict[str, float]:
    """The figures of one :class:`~spade.closedloop.simulate.Episode` (module docstring); NaN where undefined."""
    sc = episode.scenario
    k = len(sc.demonstration)
    executed = np.asarray(episode.path, np.float64)[:, :2]
    nan = float("nan")
    figures = {name: float(episode.outcome == name) for name in ("success", "collision", "no_plan", "timeout")}
    paths = np.stack([resample_polyline(p, k) for p in sc.plausible()])
    if len(executed) >= 2 and polyline_length(executed) > 0:
        dist = np.linalg.norm(paths - resample_polyline(executed, k)[None], axis=2).mean(axis=1) * 100.0
    else:
        dist = np.linalg.norm(paths - executed[0][None, None], axis=2).mean(axis=1) * 100.0
    figures["ape_cm"] = float(dist[0])
    has_alternatives = len(paths) > 1
    figures["plausibility_cm"] = float(dist.min()) if has_alternatives else nan
    figures["commit"] = float(dist.min() <= commit_tol_cm) if has_alternatives else nan
    figures["length_ratio"] = polyline_length(executed) / max(sc.length_m, 1e-9) if episode.success else nan
    figures["smoothness_deg_per_m"] = smoothness(executed)
    plans = [p for p in episode.plans if len(p.waypoints) >= 2]
    changes = [_overlap_change(a.waypoints, b.waypoints, k) for a, b in zip(plans[:-1], plans[1:])]
    changes = [c for c in changes if math.isfinite(c)]
    figures["replan_change_cm"] = float(np.mean(changes)) * 100.0 if changes else nan
    modes = [m for m in (plan_mode(_beyond(p.waypoints, JOIN_M), sc.radius_boundary_m, min_turn_deg) for p in plans)
             if m is not None]
    figures["mode_switches"] = float(sum(a != b for a, b in zip(modes[:-1], modes[1:])))
    figures["plan_ms"] = float(np.mean([p.seconds for p in episode.plans])) * 1000.0 if episode.plans else nan
    figures["replans"] = float(len(episode.plans))
    return figures


class ClosedLoopMetrics(Metric):
    """Rates and means of closed-loop episodes (:data:`CLOSED_LOOP_KEYS`): the outcome rates over every episode;
    ``ape_cm``, ``smoothness_deg_per_m``, ``mode_switches``, ``plan_ms``, ``replans`` over every episode;
    ``plausibility_cm`` and ``commit_rate`` over those with alternatives; ``length_ratio`` over the successes;
    ``replan_change_cm`` over those that replanned."""

    is_differentiable = False
    higher_is_better = None
    full_state_update = False

    def __init__(self, commit_tol_cm: float = 1.5, min_turn_deg: float = 45.0, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        if not commit_tol_cm > 0:
            raise ValueError(f"commit_tol_cm must be > 0 centimetres, got {commit_tol_cm}")
        self.commit_tol_cm, self.min_turn_deg = float(commit_tol_cm), float(min_turn_deg)
        for name in FIGURES:
            self.add_state(name, default=[], dist_reduce_fx="cat")

    def update(self, episodes: list[Any]) -> None:
        rows = [episode_figures(e, self.commit_tol_cm, self.min_turn_deg) for e in episodes]
        for name in FIGURES:
            append_state(self, name, [r[name] for r in rows])

    def compute(self) -> dict[str, torch.Tensor]:
        def mean(name: str) -> torch.Tensor:
            v = cat_state(getattr(self, name))
            v = v[~torch.isnan(v)]
            return v.mean() if v.numel() else torch.tensor(float("nan"), dtype=torch.float64)

        out = {f"{o}_rate": mean(o) for o in ("success", "collision", "no_plan", "timeout")}
        out.update({name: mean(name) for name in ("ape_cm", "plausibility_cm", "length_ratio", "smoothness_deg_per_m",
                                                  "replan_change_cm", "mode_switches", "plan_ms", "replans")})
        out["commit_rate"] = mean("commit")
        out["episodes"] = torch.tensor(float(cat_state(self.success).numel()), dtype=torch.float64)
        return {k: out[k] for k in CLOSED_LOOP_KEYS}
