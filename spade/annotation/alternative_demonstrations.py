"""Alternative demonstrations: what else the generator could have drawn from the state a student sees.

A demonstration is one draw among many: for an L, the robot's pose and the goal fix two of leg, radius and tail,
not all three, and the radius band (sharp or wide) is a free choice. An instance's *alternatives* are other draws
of the same generator that agree with everything its window shows: same map, same goal, an executed path that
passes through the robot's pose with its heading. They make the metrics of :mod:`spade.metrics.preference`
possible (the ambiguity floor, plausibility, commitment).

The estimator (version :data:`ALTERNATIVES_VERSION`) is rejection sampling of the generator's prior, per scenario
and shared by all of its robot states:

1. Draw templates from the generator's own prior (:func:`sample_templates`, the distribution of
   :func:`spade.annotation.templates.sample_template`, vectorised), placed on the scenario's goal. The first leg's
   heading is drawn only over the arc of headings whose curve can pass one of the states (the same width for
   both turn directions, the prior's ``heading_deg`` applied by rejection), which leaves the conditional
   distribution unchanged and saves most draws.
2. Prefilter, vectorised over the draws (:func:`keypoints_pass`): the polyline through the template's clicked
   waypoints (the chords the execution follows before it smooths them) passes within ``prefilter_px`` of a state
   with a heading within ``prefilter_deg``. The ideal curve is a poor proxy: an executed path that passes a pose
   exactly has its ideal arc up to 30 degrees off there, its chords within 20.
3. Execute each candidate once per scenario, as the generator does (every check of a scenario: sketch clearance,
   window fit, :func:`spade.annotation.execution.execute_sketch`'s deviation and shape checks).
4. Keep it for a state when the *executed* path passes within ``pos_tol_px`` of the robot with a heading within
   ``heading_tol_deg`` (the demonstration itself passes at 0): the alternative is that path from its point nearest
   the robot to the goal, its start moved onto the robot by a ramp that fades out along it, in the state's window
   frame, resampled to the dataset's ``num_waypoints``.

Up to ``count`` alternatives per state; fewer where the draw budget (``max_draws`` per scenario) runs out, and the
manifest says how many. Draws come from a generator seeded by the scenario, so the output never depends on the
worker count or chunking. ``python -m spade.perf.alternatives`` measures the prefilter's loss against a looser one.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from spade.annotation.execution import Rejection, execute_sketch
from spade.annotation.templates import SHAPES, place_curves, sketch_fits, turn_curve
from spade.data.polyline import resample_polyline
from spade.data.rasterize import fits_robot_frame
from spade.maps.frame import RobotFrame, path_heading

ALTERNATIVES_VERSION = 1
"""Bumped whenever the estimator changes what it draws; recorded in the manifest."""

ESTIMATOR = ("rejection sampling of the generator's templates on the goal: executed as the generator does, kept "
             "where the executed path passes the robot within pos_tol_px and heading_tol_deg (prefilter: the clicked "
             "waypoints' polyline within prefilter_px, prefilter_deg); the executed path from its nearest point to "
             "the goal, start ramped onto the robot")

__all__ = ["ALTERNATIVES_VERSION", "ESTIMATOR", "AlternativesSettings", "TemplateDraws", "execute_template",
           "heading_window", "in_heading_prior", "keypoint_polylines", "keypoints_pass", "remaining_path",
           "sample_templates", "scenario_alternatives"]


@dataclass(frozen=True)
class AlternativesSettings:
    """``alternatives`` config section of ``spade.annotate``."""

    count: int = 0  # alternatives per instance (0: none)
    pos_tol_px: float = 0.75  # the executed path passes this close to the robot's position
    heading_tol_deg: float = 3.0  # ... with a heading this close to the robot's
    prefilter_px: float = 3.0  # candidates: the clicked waypoints' polyline passes this close to the robot ...
    prefilter_deg: float = 20.0  # ... with a heading this close
    batch: int = 4096  # templates drawn per round
    max_draws: int = 200_000  # per scenario
    shapes: tuple[str, ...] | None = None  # the shapes whose instances get them (None: every shape)

    @classmethod
    def from_cfg(cls, cfg: Mapping[str, Any] | None) -> "AlternativesSettings":
        cfg = dict(cfg or {})
        known = set(cls.__dataclass_fields__)
        unknown = sorted(set(cfg) - known)
        if unknown:
            raise ValueError(f"alternatives has no key(s) {unknown}; known: {sorted(known)}")
        shapes = cfg.pop("shapes", None)
        out = cls(**{k: type(getattr(cls, k))(v) for k, v in cfg.items() if v is not None},
                  shapes=None if shapes is None else tuple(str(v) for v in ([shapes] if isinstance(shapes, str)
                                                                             else shapes)))
        unknown_shapes = sorted(set(out.shapes or ()) - set(SHAPES))
        if unknown_shapes:
            raise ValueError(f"alternatives.shapes has unknown shape(s) {unknown_shapes}; known: {sorted(SHAPES)}")
        for name in ("pos_tol_px", "heading_tol_deg", "prefilter_px", "prefilter_deg"):
            if not getattr(out, name) > 0:
                raise ValueError(f"alternatives.{name} must be > 0, got {getattr(out, name)}")
        if out.count < 0 or out.count > 255:
            raise ValueError(f"alternatives.count must lie in 0..255, got {out.count}")
        if out.batch < 1 or out.max_draws < out.batch:
            raise ValueError(f"alternatives.batch ({out.batch}) must be >= 1 and <= max_draws ({out.max_draws})")
        return out

    def to_json(self) -> dict[str, Any]:
        out = {k: getattr(self, k) for k in self.__dataclass_fields__}
        out["shapes"] = None if self.shapes is None else list(self.shapes)
        return out

    def wanted(self, shape: str) -> bool:
        """Whether instances of ``shape`` get alternatives."""
        return self.count > 0 and (self.shapes is None or shape in self.shapes)


@dataclass(frozen=True)
class TemplateDraws:
    """B templates of one shape as arrays, in their own frame (start at the origin, leg along +x, metres)."""

    leg: np.ndarray
    radius: np.ndarray
    tail: np.ndarray
    sign: np.ndarray  # +1: left turn, -1: right turn (mirror)
    theta: np.ndarray  # heading of the first leg, radians counter-clockwise with y up
    turn: float  # radians

    def __len__(self) -> int:
        return len(self.leg)

    def end(self) -> np.ndarray:
        """(B, 2) end of the tail (the goal) in the template frame."""
        c = np.stack([self.leg, self.sign * self.radius], axis=1)
        arc_end = c + self.radius[:, None] * np.stack([np.full_like(self.leg, np.sin(self.turn)),
                                                        -self.sign * np.cos(self.turn)], axis=1)
        u = np.stack([np.full_like(self.leg, np.cos(self.turn)), self.sign * np.sin(self.turn)], axis=1)
        return arc_end + self.tail[:, None] * u


def sample_templates(shape: str, cfg: Mapping[str, Any], rng: np.random.Generator, n: int,
                     theta_range: tuple[np.ndarray, float] | None = None) -> TemplateDraws:
    """``n`` templates from the distribution of :func:`~spade.annotation.templates.sample_template` (``cfg``: the
    ``template`` config section). ``theta_range`` = (start per turn direction {+1, -1} -> angle, width): draw the
    heading uniformly over [start, start + width) for the drawn direction instead of over ``heading_deg`` (the
    caller restricts it to headings that can pass its pose; the prior over ``heading_deg`` is then applied by
    rejection, see :func:`scenario_alternatives`)."""
    s = cfg[shape]
    leg = rng.uniform(float(s["leg_m"][0]), float(s["leg_m"][1]), n)
    wide = rng.random(n) < float(s["p_wide"])
    r_lo = np.where(wide, float(s["radius_m"]["wide"][0]), float(s["radius_m"]["sharp"][0]))
    r_hi = np.where(wide, float(s["radius_m"]["wide"][1]), float(s["radius_m"]["sharp"][1]))
    radius = r_lo + (r_hi - r_lo) * rng.random(n)
    large = rng.random(n) < float(s["p_large_tail"])
    t_lo = np.where(large, float(s["tail_m"]["large"][0]), float(s["tail_m"]["small"][0]))
    t_hi = np.where(large, float(s["tail_m"]["large"][1]), float(s["tail_m"]["small"][1]))
    tail = t_lo + (t_hi - t_lo) * rng.random(n)
    sign = np.where(rng.random(n) < float(cfg["p_mirror"]), -1.0, 1.0)
    if theta_range is None:
        lo, hi = np.deg2rad(float(cfg["heading_deg"][0])), np.deg2rad(float(cfg["heading_deg"][1]))
        theta = rng.uniform(lo, hi, n)
    else:
        starts, width = theta_range
        theta = np.where(sign > 0, starts[0], starts[1]) + width * rng.random(n)
    return TemplateDraws(leg, radius, tail, sign, theta, float(np.deg2rad(SHAPES[shape])))


def _wrap(a: np.ndarray) -> np.ndarray:
    return (a + np.pi) % (2 * np.pi) - np.pi


def heading_window(poses: np.ndarray, turn: float, heading_tol: float) -> tuple[np.ndarray, float]:
    """Per turn direction, the start of an arc of first-leg headings of one width that holds every heading that
    can pass any of ``poses``: for a left turn theta in [psi - turn - tol, psi + tol] (the robot on the leg, the
    arc or the tail), mirrored for a right turn; the union over the poses' headings, as one arc."""
    psi = np.unwrap(-poses[:, 2])  # y-up headings, continuous along the path
    lo, hi = float(psi.min()), float(psi.max())
    width = (hi - lo) + turn + 2 * heading_tol
    if width >= 2 * np.pi:
        return np.array([0.0, 0.0]), 2 * np.pi
    left = lo - turn - heading_tol
    right = lo - heading_tol
    return np.array([left, right]), width


def in_heading_prior(theta: np.ndarray, cfg: Mapping[str, Any]) -> np.ndarray:
    """Whether each heading lies in ``template.heading_deg`` (modulo a full turn)."""
    lo, hi = np.deg2rad(float(cfg["heading_deg"][0])), np.deg2rad(float(cfg["heading_deg"][1]))
    if hi - lo >= 2 * np.pi - 1e-12:
        return np.ones(theta.shape, dtype=bool)
    return (theta - lo) % (2 * np.pi) <= (hi - lo)


def _place(t: TemplateDraws, b: int, goal_px: np.ndarray, resolution: float, cfg: Mapping[str, Any],
           shape: str) -> tuple[np.ndarray, np.ndarray]:
    """(keypoints, dense) of template ``b`` in map pixels, as :func:`~spade.annotation.templates.place_template`."""
    left = bool(t.sign[b] > 0)
    keypoints, dense = turn_curve(float(t.leg[b]), float(t.radius[b]), float(t.tail[b]), SHAPES[shape], left,
                                   float(cfg["step_m"]), int(cfg[shape]["turn_keypoints"]),
                                   float(cfg["keypoint_spacing_m"]))
    return place_curves(keypoints, dense, float(t.theta[b]), goal_px, resolution)


def remaining_path(points: np.ndarray, pose: np.ndarray, frame: RobotFrame, num_points: int, pos_tol_px: float,
                   heading_tol: float) -> np.ndarray | None:
    """The executed path from its point nearest the pose's position to the goal, in the pose's window frame, its
    start moved onto the robot by a ramp that fades out along it; None unless it passes within ``pos_tol_px`` of
    the robot with a heading within ``heading_tol`` radians."""
    dist = np.linalg.norm(points - pose[:2], axis=1)
    i = int(np.argmin(dist))
    if dist[i] > pos_tol_px or i >= len(points) - 2:
        return None
    if abs(float(_wrap(np.array(path_heading(points, i) - pose[2])))) > heading_tol:
        return None
    rest = points[i:].copy()
    seg = np.linalg.norm(np.diff(rest, axis=0), axis=1)
    u = np.concatenate([[0.0], np.cumsum(seg)])
    u = u / u[-1] if u[-1] > 0 else u
    rest += (1.0 - u)[:, None] * (pose[:2] - rest[0])
    local = frame.place(pose[:2], float(pose[2])).to_window(rest)
    return resample_polyline(local, num_points)


def _nearest_distance(path: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """(S,) distance of each position to the nearest point of ``path`` (pixels)."""
    from scipy.spatial import cKDTree

    return cKDTree(path).query(positions)[0]


def execute_template(costmap: Any, t: TemplateDraws, b: int, goal_px: np.ndarray, cfg: Mapping[str, Any],
                     shape: str, frame: RobotFrame) -> np.ndarray | None:
    """Template ``b`` placed on the goal and executed with every check a scenario applies; None if rejected."""
    res = float(costmap.resolution)
    margin = float(cfg["window"]["margin_m"]) / res
    keypoints, dense = _place(t, b, goal_px, res, cfg["template"], shape)
    if not sketch_fits(costmap, dense, frame, margin, float(cfg["scenario"]["sketch_clearance_m"]) / res):
        return None
    try:
        ex = execute_sketch(costmap, keypoints, dense, SHAPES[shape], cfg["execution"])
    except Rejection:
        return None
    return ex.points if fits_robot_frame(ex.points, frame, margin) else None


def scenario_alternatives(costmap: Any, shape: str, goal_px: np.ndarray, points: np.ndarray,
                          state_indices: np.ndarray, cfg: Mapping[str, Any], settings: AlternativesSettings,
                          rng: np.random.Generator) -> tuple[dict[int, np.ndarray], dict[str, int]]:
    """Alternatives of the robot states ``points[i]`` (``i`` in ``state_indices``) of one executed scenario path.

    ``costmap``: the map's :class:`~spade.maps.costmap.Costmap`; ``goal_px``: the scenario's goal (map pixels,
    where its template ended); ``cfg``: the annotate config. Returns {state index: (k, num_waypoints, 2) window
    pixel polylines, k <= count} and counters (draws, prefiltered candidates, executed, accepted)."""
    stats = {"draws": 0, "candidates": 0, "executed": 0, "accepted": 0}
    if settings.count <= 0 or len(state_indices) == 0:
        return {}, stats
    frame = RobotFrame.for_size(int(cfg["window"]["size_px"]))
    res = float(costmap.resolution)
    k = int(cfg["num_waypoints"])
    idx = np.asarray(state_indices, dtype=np.int64)
    poses = np.stack([np.r_[points[i], path_heading(points, int(i))] for i in idx])
    heading_tol = np.deg2rad(settings.heading_tol_deg)
    pre_px = settings.prefilter_px
    pre_heading = np.deg2rad(max(settings.prefilter_deg, settings.heading_tol_deg))
    window = heading_window(poses, float(np.deg2rad(SHAPES[shape])), pre_heading)
    out: list[list[np.ndarray]] = [[] for _ in idx]
    while stats["draws"] < settings.max_draws:
        wanting = np.array([len(v) < settings.count for v in out])
        if not wanting.any():
            break
        t = sample_templates(shape, cfg["template"], rng, settings.batch, theta_range=window)
        stats["draws"] += settings.batch
        hit = keypoints_pass(t, goal_px, poses[wanting], res, pre_px, pre_heading, cfg["template"], shape)
        hit &= in_heading_prior(t.theta, cfg["template"])[:, None]
        for b in np.flatnonzero(hit.any(axis=1)):
            wanting = np.array([len(v) < settings.count for v in out])
            if not wanting.any():
                break
            stats["candidates"] += 1
            path = execute_template(costmap, t, b, goal_px, cfg, shape, frame)
            if path is None:
                continue
            stats["executed"] += 1
            # every state still wanting is checked on the executed path, not only those its sketch passed near
            near = np.flatnonzero(wanting & (_nearest_distance(path, poses[:, :2]) <= settings.pos_tol_px))
            for j in near:
                rest = remaining_path(path, poses[j], frame, k, settings.pos_tol_px, heading_tol)
                if rest is not None:
                    out[j].append(rest)
                    stats["accepted"] += 1
    return ({int(i): np.stack(v).astype(np.float32) if v else np.zeros((0, k, 2), np.float32)
             for i, v in zip(idx, out)}, stats)


def keypoint_polylines(t: TemplateDraws, cfg: Mapping[str, Any], shape: str) -> tuple[np.ndarray, np.ndarray]:
    """(B, N, 2) the waypoints an operator clicks for each template (:func:`~spade.annotation.templates.turn_curve`'s
    keypoints, in the template frame, metres), padded by repeating the last, and (B,) how many each has."""
    spacing = float(cfg["keypoint_spacing_m"])
    turn_kp = int(cfg[shape]["turn_keypoints"])
    n_leg = np.maximum(1, np.ceil(t.leg / spacing)).astype(np.int64)
    n_tail = np.maximum(1, np.ceil(t.tail / spacing)).astype(np.int64)
    n_arc = turn_kp + 2
    counts = n_leg + n_arc + n_tail
    width = int(counts.max())
    b = len(t)
    j = np.arange(width)[None, :].repeat(b, axis=0)
    out = np.zeros((b, width, 2))
    # leg: i * leg / n_leg for i < n_leg
    on_leg = j < n_leg[:, None]
    out[..., 0] = np.where(on_leg, j * (t.leg / n_leg)[:, None], 0.0)
    # arc: phi = linspace(0, turn, n_arc)
    a = j - n_leg[:, None]
    on_arc = (a >= 0) & (a < n_arc)
    phi = np.clip(a, 0, n_arc - 1) * (t.turn / (n_arc - 1))
    r, sign = t.radius[:, None], t.sign[:, None]
    arc_x = t.leg[:, None] + r * np.sin(phi)
    arc_y = sign * r - sign * r * np.cos(phi)
    out[..., 0] = np.where(on_arc, arc_x, out[..., 0])
    out[..., 1] = np.where(on_arc, arc_y, out[..., 1])
    # tail: arc end + (i + 1) * tail / n_tail along the final heading, i < n_tail
    e = j - n_leg[:, None] - n_arc
    on_tail = e >= 0
    along = np.minimum(e + 1, n_tail[:, None]) * (t.tail / n_tail)[:, None]
    end_x = t.leg + t.radius * np.sin(t.turn)
    end_y = t.sign * t.radius * (1 - np.cos(t.turn))
    out[..., 0] = np.where(on_tail, end_x[:, None] + along * np.cos(t.turn), out[..., 0])
    out[..., 1] = np.where(on_tail, end_y[:, None] + along * sign * np.sin(t.turn), out[..., 1])
    return out, counts


def _in_template_frame(t: TemplateDraws, goal_px: np.ndarray, poses: np.ndarray, resolution: float
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The poses (S, 3: map pixels and map-pixel heading) in each template's frame: x, y (B, S) metres and the
    heading (B, S), for templates placed so that they end on ``goal_px``."""
    end = t.end()
    d = np.stack([(poses[:, 0] - goal_px[0]) * resolution, -(poses[:, 1] - goal_px[1]) * resolution], axis=1)
    c, s = np.cos(t.theta)[:, None], np.sin(t.theta)[:, None]
    qx = c * d[None, :, 0] + s * d[None, :, 1] + end[:, 0:1]
    qy = -s * d[None, :, 0] + c * d[None, :, 1] + end[:, 1:2]
    return qx, qy, _wrap(-poses[None, :, 2] - t.theta[:, None])


def keypoints_pass(t: TemplateDraws, goal_px: np.ndarray, poses: np.ndarray, resolution: float, pos_tol_px: float,
                   heading_tol: float, cfg: Mapping[str, Any], shape: str) -> np.ndarray:
    """(B, S) whether the polyline through template b's clicked waypoints (the chords an execution follows before
    smoothing) passes within ``pos_tol_px`` of pose s with a heading within ``heading_tol`` radians."""
    qx, qy, psi = _in_template_frame(t, goal_px, poses, resolution)
    kp, _ = keypoint_polylines(t, cfg, shape)
    a, b = kp[:, :-1], kp[:, 1:]  # (B, N-1, 2)
    seg = b - a
    length2 = (seg ** 2).sum(-1)
    valid = length2 > 1e-12
    heading = np.arctan2(seg[..., 1], seg[..., 0])
    tol = pos_tol_px * resolution
    out = np.zeros(qx.shape, dtype=bool)
    for k in range(seg.shape[1]):  # segments one at a time: (B, S) arrays, a few dozen at most
        ax, ay = a[:, k, 0:1], a[:, k, 1:2]
        sx, sy = seg[:, k, 0:1], seg[:, k, 1:2]
        l2 = np.where(valid[:, k:k + 1], length2[:, k:k + 1], 1.0)
        u = np.clip(((qx - ax) * sx + (qy - ay) * sy) / l2, 0.0, 1.0)
        dist = np.hypot(qx - ax - u * sx, qy - ay - u * sy)
        ok = (dist <= tol) & (np.abs(_wrap(psi - heading[:, k:k + 1])) <= heading_tol) & valid[:, k:k + 1]
        out |= ok
    return out
