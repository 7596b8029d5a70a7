"""Robot-frame L / U / straight path sets with controlled shape changes: what the FID validity tests and the
benchmark compare (see :mod:`spade.metrics.shape_features`).

Each path is the *remaining* path of one robot state along an ideal annotation template (a straight leg, a
circular turn of 90 degrees for L or 180 for U, a straight tail; the ranges of ``conf/annotate.yaml``'s
``template`` section, in metres), seen in the robot's frame exactly as a dataset window shows it
(:mod:`spade.maps.frame`: robot at (W/2, 3W/4), heading up, the whole path at least 0.3 m inside the
window), and drawn like a dataset's ``path`` channel (the one-pixel curve of
:func:`spade.data.rasterize.draw_curve`). No map and no planner: the geometry alone, deterministic by
seed, on any window size (64 px at 0.1 m/px and 128 px at 0.05 m/px cover the same 6.4 m).

Shape changes are parameters of the draw (``radius_scale``: 0 turns every arc into a sharp corner; ``shape``)
or of the rendering (:func:`render_paths`: a gap cut out of the middle of each path, a shift), so a corrupted
set differs from its clean twin (same seed) by that change only.
"""

from __future__ import annotations

from typing import Any, Mapping, Sequence

import numpy as np

from spade.data.polyline import polyline_length, resample_polyline
from spade.data.rasterize import draw_curve

__all__ = ["TEMPLATE", "sample_paths", "render_paths", "straight_paths", "rotate_paths", "cut_gap", "template_curve",
           "to_robot_frame"]

TEMPLATE: dict[str, Any] = {
    "heading_deg": [0.0, 360.0],
    "p_mirror": 0.5,
    "L": {"leg_m": [1.0, 2.6], "radius_m": {"sharp": [0.25, 0.5], "wide": [0.7, 1.0]}, "p_wide": 0.5,
          "tail_m": {"small": [0.25, 0.6], "large": [0.9, 1.7]}, "p_large_tail": 0.5, "turn_deg": 90.0},
    "U": {"leg_m": [1.4, 2.8], "radius_m": {"sharp": [0.3, 0.5], "wide": [0.6, 0.9]}, "p_wide": 0.5,
          "tail_m": {"small": [0.3, 0.9], "large": [1.2, 2.4]}, "p_large_tail": 0.5, "turn_deg": 180.0},
}
"""The annotation tool's template ranges (``conf/annotate.yaml``, metres and degrees)."""

MARGIN_M = 0.3  # window.margin_m
MIN_REMAINING_M = 0.3  # instances.min_remaining_m
LOOKAHEAD_PX = 2.0  # the heading of a state: towards the first point this far ahead


def template_curve(leg: float, radius: float, tail: float, turn_deg: float, left: bool, step: float) -> np.ndarray:
    """Leg along +x from the origin, a circular turn of ``turn_deg`` to the left (y > 0) or right, a tail; dense
    points ``step`` apart (any unit). ``radius`` 0 gives a sharp corner."""
    sign = 1.0 if left else -1.0
    turn = np.deg2rad(turn_deg)
    n_leg = max(2, int(np.ceil(leg / step)) + 1)
    leg_pts = np.stack([np.linspace(0.0, leg, n_leg), np.zeros(n_leg)], axis=1)
    centre = np.array([leg, sign * radius])
    phi = np.linspace(0.0, turn, max(2, int(np.ceil(radius * turn / step)) + 1))
    arc = centre + radius * np.stack([np.sin(phi), -sign * np.cos(phi)], axis=1)
    end_dir = np.array([np.cos(sign * turn), np.sin(sign * turn)])
    n_tail = max(2, int(np.ceil(tail / step)) + 1)
    tail_pts = arc[-1] + np.linspace(0.0, tail, n_tail)[:, None] * end_dir
    return np.concatenate([leg_pts, arc[1:], tail_pts[1:]])


def _draw_params(shape: str, cfg: Mapping[str, Any], rng: np.random.Generator) -> dict[str, float]:
    s = cfg[shape]
    leg = rng.uniform(*s["leg_m"])
    radius = rng.uniform(*s["radius_m"]["wide" if rng.random() < s["p_wide"] else "sharp"])
    tail = rng.uniform(*s["tail_m"]["large" if rng.random() < s["p_large_tail"] else "small"])
    left = bool(rng.random() >= cfg["p_mirror"])
    return {"leg": leg, "radius": radius, "tail": tail, "left": left, "turn_deg": float(s["turn_deg"])}


def to_robot_frame(remaining: np.ndarray, size: int) -> np.ndarray:
    """Template-frame points (x forward, y left; pixels) -> window pixels, robot at (W/2, 3W/4) heading up."""
    p0 = remaining[0]
    d = np.linalg.norm(remaining - p0, axis=1)
    far = np.flatnonzero(d >= LOOKAHEAD_PX)
    h = remaining[far[0] if len(far) else -1] - p0
    h = h / np.linalg.norm(h)
    left = np.array([-h[1], h[0]])
    rel = remaining - p0
    fwd, lat = rel @ h, rel @ left
    return np.stack([size / 2.0 - lat, 0.75 * size - fwd], axis=1)


def sample_paths(n: int, shape: str = "L", size: int = 64, resolution: float = 0.1, seed: int = 0,
                 radius_scale: float = 1.0, template: Mapping[str, Any] = TEMPLATE) -> list[np.ndarray]:
    """``n`` remaining paths (window pixel polylines, from the robot to the goal) of ``shape`` ("L" or "U").

    Per path: one template draw, one robot state uniformly along it (leaving at least 0.3 m to drive), redrawn
    until the remaining path lies 0.3 m inside the window (as the annotation tool skips such states). The draws
    do not depend on ``radius_scale`` (which multiplies every turn radius after the draw), so the same seed
    gives the same legs, tails, turn directions and states at every scale.
    """
    if shape not in ("L", "U"):
        raise ValueError(f"unknown shape {shape!r}; use 'L' or 'U'")
    rng = np.random.default_rng(seed)
    step = 0.5  # px
    margin = MARGIN_M / resolution
    out: list[np.ndarray] = []
    while len(out) < n:
        p = _draw_params(shape, template, rng)
        s_frac = rng.random()
        dense = template_curve(p["leg"] / resolution, p["radius"] * radius_scale / resolution,
                               p["tail"] / resolution, p["turn_deg"], p["left"], step)
        length = polyline_length(dense)
        last = length - MIN_REMAINING_M / resolution
        if last <= 0:
            continue
        cum = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(dense, axis=0), axis=1))])
        i = int(np.searchsorted(cum, s_frac * last, side="right")) - 1
        remaining = dense[i:]
        local = to_robot_frame(remaining, size)
        if ((local >= margin) & (local <= size - 1 - margin)).all():
            out.append(local)
    return out


def straight_paths(paths: Sequence[np.ndarray]) -> list[np.ndarray]:
    """The straight segment from each path's start to its goal (the ``straight`` baseline)."""
    return [np.stack([p[0], p[-1]]) for p in paths]


def rotate_paths(paths: Sequence[np.ndarray], size: int) -> list[np.ndarray]:
    """Each path rotated by 180 degrees about the window centre."""
    return [(size - 1.0) - np.asarray(p, np.float64) for p in paths]


def cut_gap(points: np.ndarray, fraction: float, where: float = 0.5) -> list[np.ndarray]:
    """The pieces left of a polyline when ``fraction`` of its arc length, centred at ``where`` (a fraction of
    the arc length), is removed: [before, after] (one piece when nothing is removed)."""
    pts = np.asarray(points, np.float64)
    if fraction <= 0:
        return [pts]
    dense = resample_polyline(pts, max(8, int(np.ceil(polyline_length(pts) * 4)) + 1))
    k = len(dense)
    a = int(round(np.clip(where - fraction / 2, 0, 1) * (k - 1)))
    b = int(round(np.clip(where + fraction / 2, 0, 1) * (k - 1)))
    return [piece for piece in (dense[: a + 1], dense[b:]) if len(piece) and b > a] or [pts]


def render_paths(paths: Sequence[np.ndarray], size: int, gap: float = 0.0, shift_px: float = 0.0,
                 seed: int = 0) -> np.ndarray:
    """(n, 1, size, size) float32 images of the paths drawn like a dataset's ``path`` channel.

    ``gap``: the middle ``gap`` fraction of each path's arc length removed (1/3: its middle third);
    ``shift_px``: each path translated by that many pixels in a random direction (deterministic by ``seed``).
    """
    rng = np.random.default_rng(seed)
    out = np.zeros((len(paths), 1, size, size), dtype=np.float32)
    for i, p in enumerate(paths):
        pts = np.asarray(p, np.float64)
        if shift_px:
            ang = rng.uniform(0, 2 * np.pi)
            pts = pts + shift_px * np.array([np.cos(ang), np.sin(ang)])
        for piece in cut_gap(pts, gap):
            piece = np.clip(piece, 0, size - 1)
            out[i, 0] = np.maximum(out[i, 0], draw_curve(piece, size))
    return out
