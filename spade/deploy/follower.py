"""A path follower for the closed loop: pure pursuit on a differential-drive robot, as Nav2's Regulated Pure
Pursuit controller drives a global plan.

Each control step the robot looks ``lookahead_m`` along the plan ahead of its nearest point, steers on the arc
through that point (curvature ``2 y / L^2`` in the robot's frame), at ``speed_mps`` unless the angular limit
``max_angular_rps`` regulates the speed down; a look-ahead point more than ``rotate_deg`` off its heading makes it
turn on the spot first (Nav2's ``use_rotate_to_heading``). Near the plan's end it slows so as not to overshoot.
Defaults: a TurtleBot3 Burger (0.22 m/s, 2.84 rad/s), Nav2's minimum look-ahead (0.3 m), a 10 Hz controller.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["FollowerSettings", "follow_step", "lookahead_point"]


@dataclass(frozen=True)
class FollowerSettings:
    speed_mps: float = 0.22
    lookahead_m: float = 0.3
    max_angular_rps: float = 2.84
    rotate_deg: float = 60.0
    dt_s: float = 0.1

    def __post_init__(self) -> None:
        for name in ("speed_mps", "lookahead_m", "max_angular_rps", "dt_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"follower {name} must be a positive number, got {value!r}")
        if not 0 < self.rotate_deg <= 180:
            raise ValueError(f"follower rotate_deg must lie in (0, 180], got {self.rotate_deg!r}")


def lookahead_point(position: np.ndarray, plan: np.ndarray, lookahead_m: float) -> np.ndarray:
    """The point ``lookahead_m`` along ``plan`` (K, 2) beyond the plan point nearest to ``position`` (its end when
    the plan is shorter)."""
    pts = np.asarray(plan, np.float64)
    seg = np.diff(pts, axis=0)
    lengths = np.linalg.norm(seg, axis=1)
    den = np.maximum(lengths ** 2, 1e-18)
    t = np.clip(((position - pts[:-1]) * seg).sum(axis=1) / den, 0.0, 1.0)
    near = pts[:-1] + t[:, None] * seg
    k = int(np.argmin(np.linalg.norm(near - position, axis=1)))
    along = np.concatenate([[0.0], np.cumsum(lengths)])
    target = along[k] + t[k] * lengths[k] + lookahead_m
    if target >= along[-1]:
        return pts[-1].copy()
    j = int(np.searchsorted(along, target, side="right")) - 1
    f = (target - along[j]) / max(lengths[j], 1e-12)
    return pts[j] + f * seg[j]


def follow_step(pose: np.ndarray, plan: np.ndarray, settings: FollowerSettings,
                believed: np.ndarray | None = None) -> np.ndarray:
    """The robot's pose (x, y, yaw) one control step later. The controller steers from ``believed`` (its
    localisation; default the true ``pose``), the motion is applied to the true ``pose``."""
    s = settings
    belief = np.asarray(pose if believed is None else believed, np.float64)
    target = lookahead_point(belief[:2], plan, s.lookahead_m)
    d = target - belief[:2]
    c, si = math.cos(belief[2]), math.sin(belief[2])
    x, y = c * d[0] + si * d[1], -si * d[0] + c * d[1]  # in the robot's frame: x ahead, y to the left
    dist = math.hypot(x, y)
    if dist < 1e-9:
        return np.asarray(pose, np.float64).copy()
    angle = math.atan2(y, x)
    if abs(angle) > math.radians(s.rotate_deg):
        v, w = 0.0, math.copysign(min(s.max_angular_rps, abs(angle) / s.dt_s), angle)
    else:
        goal_left = float(np.linalg.norm(np.asarray(plan[-1], np.float64) - belief[:2]))
        v = min(s.speed_mps, goal_left / s.dt_s)
        kappa = 2.0 * y / (dist * dist)
        w = v * kappa
        if abs(w) > s.max_angular_rps:  # regulated: slow down for the curvature
            w = math.copysign(s.max_angular_rps, w)
            v = s.max_angular_rps / abs(kappa)
    px, py, th = (float(v) for v in np.asarray(pose, np.float64))
    dt = s.dt_s
    if abs(w) < 1e-9:
        return np.array([px + v * dt * math.cos(th), py + v * dt * math.sin(th), th])
    r = v / w
    th2 = th + w * dt
    return np.array([px + r * (math.sin(th2) - math.sin(th)), py - r * (math.cos(th2) - math.cos(th)),
                     math.atan2(math.sin(th2), math.cos(th2))])
