"""Metrics that see a preference: the ambiguity floor, plausibility and commitment.

APE against the one demonstration of an instance cannot tell a good plan from the blend of two ways of turning:
the demonstration is one draw among the alternatives the same state allows (:mod:`spade.annotation.alternative_demonstrations`
draws them with the dataset). With the demonstration and its alternatives, the *plausible set* of an instance:

- ``floor_cm``: the APE (to the demonstration) of the best single path a predictor could give without knowing
  which draw was made. Estimator: the pointwise median of the plausible set (every path resampled to the same
  points by arc length), its end moved by a linear ramp along the path onto the goal *as the input shows it*: the
  weighted centroid of the goal channel (the disc's centre for the paper's binary disc at its rounded pixel, the
  exact goal for a sub-pixel encoding, :mod:`spade.data.encoding`). Averaged over instances with alternatives.
- ``ape_over_floor``: mean APE over mean floor on the same instances (the ratio of the means; 1 is the floor).
- ``plausibility_cm``: the APE to the *nearest* path of the plausible set, averaged: 0 for a path an operator
  (the generator) could have drawn, large for a blend no one drew.
- ``commit_rate``: the share of instances whose path lies within ``commit_tol_cm`` (mean distance) of one path of
  the plausible set: it chose one way of turning. A failed prediction does not commit. The tolerance is in
  centimetres so that it means the same at every resolution; ``python -m spade.perf.alternatives`` reports how
  often a genuine draw of the generator commits at it (each alternative against the rest of its set).

Instances without alternatives are left out of all four (``pref_instances`` counts those scored).
"""

from __future__ import annotations

import numpy as np
import torch
from torchmetrics import Metric

from spade.data.polyline import resample_polyline
from spade.metrics._inputs import append_state, cat_state, per_instance_resolution, to_numpy
from spade.metrics.extraction import marker_centre

__all__ = ["PREFERENCE_KEYS", "PreferenceMetrics", "SpreadMetrics", "floor_path", "medoid_path", "plausible_set"]

PREFERENCE_KEYS: tuple[str, ...] = ("ape_over_floor", "plausibility_cm", "commit_rate")
"""The per-predictor figures (a test logs them for the paper's reading and, prefixed, the planner's)."""


def plausible_set(waypoints: np.ndarray, alternatives: np.ndarray | None) -> np.ndarray:
    """(1 + k, K, 2): the demonstration then its stored alternatives (NaN padding rows dropped), each resampled
    evenly by arc length to its K points as :func:`~spade.metrics.geometry.polyline_ape` resamples a ground truth,
    so that the APE here is the APE metric's."""
    demo = np.asarray(waypoints, np.float64)
    paths = [demo]
    if alternatives is not None:
        alts = np.asarray(alternatives, np.float64)
        paths += list(alts[np.isfinite(alts).all(axis=(1, 2))])
    return np.stack([resample_polyline(p, len(demo)) for p in paths])


def floor_path(paths: np.ndarray, goal_centre: np.ndarray) -> np.ndarray:
    """The floor estimator's path: the pointwise median of ``paths`` (n, K, 2), its end ramped onto
    ``goal_centre`` (the start stays put, the correction grows linearly along the path)."""
    median = np.median(np.asarray(paths, np.float64), axis=0)
    ramp = np.linspace(0.0, 1.0, len(median))[:, None]
    return median + ramp * (np.asarray(goal_centre, np.float64) - median[-1])


def _mean_distances(pred: np.ndarray, paths: np.ndarray) -> np.ndarray:
    """Mean pointwise distance of ``pred`` (resampled to K points) to each of ``paths`` (n, K, 2)."""
    p = resample_polyline(np.asarray(pred, np.float64), paths.shape[1])
    return np.linalg.norm(paths - p[None], axis=2).mean(axis=1)


def instance_errors(polyline: np.ndarray | None, waypoints: np.ndarray, alternatives: np.ndarray | None,
                    cm_per_px: float) -> tuple[float, float]:
    """One instance's ``(ape_cm, plausibility_cm)`` of a predicted path (window pixels): its APE to the demonstration
    and to the nearest path of the plausible set (:func:`plausible_set`); NaN where the prediction failed, and a NaN
    plausibility where the instance has no alternatives."""
    if polyline is None or len(polyline) < 2:
        return float("nan"), float("nan")
    paths = plausible_set(waypoints, alternatives)
    dist = _mean_distances(polyline, paths) * cm_per_px
    return float(dist[0]), float(dist.min()) if len(paths) >= 2 else float("nan")


class PreferenceMetrics(Metric):
    """``floor_cm``, ``ape_over_floor``, ``plausibility_cm``, ``commit_rate`` (see the module docstring) of one
    predictor's polylines; additive states (``cat`` and ``sum``), so the figures are right under DDP."""

    is_differentiable = False
    higher_is_better = None
    full_state_update = False

    def __init__(self, commit_tol_cm: float = 1.5, **kwargs) -> None:
        super().__init__(**kwargs)
        if not commit_tol_cm > 0:
            raise ValueError(f"commit_tol_cm must be > 0 centimetres, got {commit_tol_cm}")
        self.commit_tol_cm = float(commit_tol_cm)
        self.add_state("floor", default=[], dist_reduce_fx="cat")  # cm, every instance with alternatives
        self.add_state("ape", default=[], dist_reduce_fx="cat")  # cm, scored instances
        self.add_state("floor_scored", default=[], dist_reduce_fx="cat")  # cm, the scored instances' floors
        self.add_state("plausibility", default=[], dist_reduce_fx="cat")  # cm, scored instances
        self.add_state("commits", default=torch.tensor(0, dtype=torch.long), dist_reduce_fx="sum")
        self.add_state("counted", default=torch.tensor(0, dtype=torch.long), dist_reduce_fx="sum")

    def update(self, polylines: list[np.ndarray | None], state: torch.Tensor, waypoints: torch.Tensor,
               alternatives: torch.Tensor, resolution: torch.Tensor | float) -> None:
        """``polylines``: one (N, 2) predicted path (window pixels) or None (a failure) per instance; ``state``
        (B, 3, H, W); ``waypoints`` (B, K, 2); ``alternatives`` (B, A, K, 2), NaN rows where fewer."""
        b = len(polylines)
        truth = to_numpy(waypoints, np.float64)
        alts = to_numpy(alternatives, np.float64)
        goals = to_numpy(state)[:, 2]
        res = per_instance_resolution(resolution, b)
        if truth.shape[0] != b or alts.shape[0] != b:
            raise ValueError(f"PreferenceMetrics got {b} polylines for {truth.shape[0]} demonstrations and "
                             f"{alts.shape[0]} rows of alternatives")
        floor, ape, floor_scored, plaus = [], [], [], []
        commits = counted = 0
        for i in range(b):
            paths = plausible_set(truth[i], alts[i])
            if len(paths) < 2:
                continue  # this instance has no alternatives
            cm = res[i] * 100.0
            f = float(np.linalg.norm(floor_path(paths, marker_centre(goals[i], "goal")) - paths[0], axis=1).mean())
            floor.append(f * cm)
            counted += 1
            if polylines[i] is None or len(polylines[i]) < 2:
                continue
            dist = _mean_distances(polylines[i], paths)
            ape.append(float(dist[0]) * cm)
            floor_scored.append(f * cm)
            plaus.append(float(dist.min()) * cm)
            commits += int(dist.min() * cm <= self.commit_tol_cm)
        for name, values in (("floor", floor), ("ape", ape), ("floor_scored", floor_scored),
                             ("plausibility", plaus)):
            append_state(self, name, values)
        self.commits += commits
        self.counted += counted

    def compute(self) -> dict[str, torch.Tensor]:
        nan = torch.tensor(float("nan"), dtype=torch.float64)
        floor, ape, floor_scored, plaus = map(cat_state, (self.floor, self.ape, self.floor_scored, self.plausibility))
        counted = self.counted.clone()
        return {
            "floor_cm": floor.mean() if floor.numel() else nan,
            "ape_over_floor": ape.mean() / floor_scored.mean() if ape.numel() and floor_scored.mean() > 0 else nan,
            "plausibility_cm": plaus.mean() if plaus.numel() else nan,
            "commit_rate": self.commits.double() / counted.double() if counted > 0 else nan,
            "pref_instances": counted,
        }


class SpreadMetrics(Metric):
    """How widely a sampler spreads its paths, against the generator's own spread (:mod:`spade.annotation.
    alternatives`): ``spread_cm``, the mean distance between two independent samples' paths of an instance (each
    resampled to K points by arc length; instances where either failed are left out); ``generator_spread_cm``, the
    mean distance between two different paths of the instance's plausible set (all pairs), over instances with
    alternatives; ``spread_ratio``: the two on the instances that have both (1: as wide as the operator's choices;
    below: too narrow, a distribution collapsed onto one turn or onto a blend)."""

    is_differentiable = False
    higher_is_better = None
    full_state_update = False

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self.add_state("spread", default=[], dist_reduce_fx="cat")  # cm, instances with two paths
        self.add_state("paired_spread", default=[], dist_reduce_fx="cat")  # cm, ... that also have alternatives
        self.add_state("generator", default=[], dist_reduce_fx="cat")  # cm, the same instances' generator spread
        self.add_state("generator_all", default=[], dist_reduce_fx="cat")  # cm, every instance with alternatives

    def update(self, first: list[np.ndarray | None], second: list[np.ndarray | None], waypoints: torch.Tensor,
               alternatives: torch.Tensor | None, resolution: torch.Tensor | float) -> None:
        """``first``, ``second``: one path (window pixels) or None per instance, from two independent samples."""
        truth = to_numpy(waypoints, np.float64)
        alts = to_numpy(alternatives, np.float64) if alternatives is not None else None
        res = per_instance_resolution(resolution, len(first))
        spread, paired, gen, gen_all = [], [], [], []
        for i, (a, b) in enumerate(zip(first, second)):
            cm = res[i] * 100.0
            g = None
            if alts is not None:
                paths = plausible_set(truth[i], alts[i])
                if len(paths) >= 2:
                    d = np.linalg.norm(paths[:, None] - paths[None], axis=3).mean(axis=2)
                    g = float(d[np.triu_indices(len(paths), 1)].mean()) * cm
                    gen_all.append(g)
            if a is None or b is None or len(a) < 2 or len(b) < 2:
                continue
            k = truth.shape[1]
            s = float(np.linalg.norm(resample_polyline(np.asarray(a, np.float64), k)
                                     - resample_polyline(np.asarray(b, np.float64), k), axis=1).mean()) * cm
            spread.append(s)
            if g is not None:
                paired.append(s)
                gen.append(g)
        for name, values in (("spread", spread), ("paired_spread", paired), ("generator", gen),
                             ("generator_all", gen_all)):
            append_state(self, name, values)

    def compute(self) -> dict[str, torch.Tensor]:
        nan = torch.tensor(float("nan"), dtype=torch.float64)
        spread, paired, gen, gen_all = map(cat_state, (self.spread, self.paired_spread, self.generator,
                                                       self.generator_all))
        return {"spread_cm": spread.mean() if spread.numel() else nan,
                "generator_spread_cm": gen_all.mean() if gen_all.numel() else nan,
                "spread_ratio": paired.mean() / gen.mean() if paired.numel() and gen.mean() > 0 else nan}


def medoid_path(paths: list[np.ndarray | None], points: int = 64) -> np.ndarray | None:
    """The minimum-Bayes-risk reading of several sampled paths of one state: the one whose mean pointwise distance
    (each resampled to ``points`` by arc length) to the others is smallest. A committed, central path, one the
    sampler actually drew (unlike the mean of the samples' maps, which blends two ways of turning). None when no
    path is given; a single path is its own medoid."""
    valid = [np.asarray(p, np.float64) for p in paths if p is not None and len(p) >= 2]
    if not valid:
        return None
    if len(valid) == 1:
        return valid[0]
    stack = np.stack([resample_polyline(p, points) for p in valid])
    dist = np.linalg.norm(stack[:, None] - stack[None], axis=3).mean(axis=2)
    return valid[int(np.argmin(dist.sum(axis=1)))]
