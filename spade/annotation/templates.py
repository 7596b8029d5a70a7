"""Sketch templates: the L and U manoeuvres an operator draws, with their per-scenario variations.

A template is one straight leg, one circular turn and one straight tail into the goal. The L-shape turns by
90 degrees, the U-shape by 180 degrees (so its tail runs back parallel to the way out). All sizes are in
metres and all angles in degrees, so the same config works at any map resolution. A placed template is checked
against the map and the robot-frame window (:func:`sketch_fits`) before it is executed.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np

from spade.data.rasterize import fits_robot_frame
from spade.maps.costmap import Costmap
from spade.maps.frame import RobotFrame
from spade.metrics.shape_paths import template_curve
from spade.utils.errors import UserError

SHAPES: dict[str, float] = {"L": 90.0, "U": 180.0}
"""Known shape labels and the net heading change (degrees) that defines each."""


class UnknownShapeError(UserError, ValueError):
    """A shape label other than the known ones was asked for."""


def check_shape(shape: str) -> str:
    """Return ``shape`` if it is a known label, else raise with the list of known labels."""
    if shape not in SHAPES:
        raise UnknownShapeError(
            f"unknown shape {shape!r}: known shapes are {sorted(SHAPES)} (use shape=L or shape=U)"
        )
    return shape


@dataclass(frozen=True)
class SketchTemplate:
    """One sampled sketch in its own frame: it ends at the origin heading along +x (the goal pose).

    ``keypoints`` are the waypoints an operator would click (start, leg end, points along the turn, goal);
    ``dense`` is the ideal curve sampled finely, used to check the placement and the executed path.
    """

    shape: str
    leg_m: float
    radius_m: float
    tail_m: float
    mirror: bool
    heading_rad: float
    keypoints: np.ndarray  # (N, 2) metres
    dense: np.ndarray  # (M, 2) metres


def _uniform(rng: np.random.Generator, bounds: Sequence[float], what: str) -> float:
    lo, hi = float(bounds[0]), float(bounds[1])
    if not (0.0 <= lo <= hi):
        raise ValueError(f"template range {what}={list(bounds)} must satisfy 0 <= low <= high")
    return float(rng.uniform(lo, hi))


def turn_curve(leg: float, radius: float, tail: float, turn_deg: float, left: bool, step: float,
                turn_keypoints: int, keypoint_spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """Leg along +x from the origin, arc of ``turn_deg`` to the left (or right), tail; in the start frame: the
    clicked keypoints and the dense ideal curve (:func:`~spade.metrics.shape_paths.template_curve`)."""
    dense = template_curve(leg, radius, tail, turn_deg, left, step)
    sign = 1.0 if left else -1.0
    turn = np.deg2rad(turn_deg)
    centre = np.array([leg, sign * radius])
    end_dir = np.array([np.cos(sign * turn), np.sin(sign * turn)])
    kp_phi = np.linspace(0.0, turn, turn_keypoints + 2)
    kp_arc = centre + radius * np.stack([np.sin(kp_phi), -sign * np.cos(kp_phi)], axis=1)
    n_kp_leg = max(1, int(np.ceil(leg / keypoint_spacing)))
    kp_leg = np.stack([np.linspace(0.0, leg, n_kp_leg + 1)[:-1], np.zeros(n_kp_leg)], axis=1)
    n_kp_tail = max(1, int(np.ceil(tail / keypoint_spacing)))
    kp_tail = kp_arc[-1] + np.linspace(0.0, tail, n_kp_tail + 1)[1:, None] * end_dir
    keypoints = np.concatenate([kp_leg, kp_arc, kp_tail])
    return keypoints, dense


def sample_template(shape: str, cfg: Mapping[str, Any], rng: np.random.Generator) -> SketchTemplate:
    """Sample one sketch of ``shape`` with the variations of ``cfg`` (the ``template`` config section).

    ``cfg`` holds ``heading_deg`` [low, high], ``p_mirror``, ``step_m``, ``keypoint_spacing_m`` (clicked
    waypoints along the straight parts) and, per shape, ``leg_m`` [low, high],
    ``radius_m`` {sharp: [..], wide: [..]}, ``p_wide``, ``tail_m`` {small: [..], large: [..]}, ``p_large_tail``
    and ``turn_keypoints`` (clicked waypoints inside the turn).
    """
    check_shape(shape)
    if shape not in cfg:
        raise ValueError(f"template config has no section for shape {shape!r}; add template.{shape}")
    s = cfg[shape]
    leg = _uniform(rng, s["leg_m"], f"template.{shape}.leg_m")
    wide = bool(rng.random() < float(s["p_wide"]))
    radius = _uniform(rng, s["radius_m"]["wide" if wide else "sharp"], f"template.{shape}.radius_m")
    large = bool(rng.random() < float(s["p_large_tail"]))
    tail = _uniform(rng, s["tail_m"]["large" if large else "small"], f"template.{shape}.tail_m")
    mirror = bool(rng.random() < float(cfg["p_mirror"]))
    heading = np.deg2rad(_uniform(rng, cfg["heading_deg"], "template.heading_deg"))
    keypoints, dense = turn_curve(leg, radius, tail, SHAPES[shape], left=not mirror, step=float(cfg["step_m"]),
                                   turn_keypoints=int(s["turn_keypoints"]),
                                   keypoint_spacing=float(cfg["keypoint_spacing_m"]))
    return SketchTemplate(shape, leg, radius, tail, mirror, float(heading), keypoints, dense)


def place_template(t: SketchTemplate, goal_px: np.ndarray, resolution: float) -> tuple[np.ndarray, np.ndarray]:
    """Return (keypoints, dense) of template ``t`` in map pixel coordinates (x=col, y=row), ending on
    ``goal_px``, its first leg pointing along the template heading (radians, counter-clockwise in the map
    frame, whose y axis points up, i.e. towards smaller rows)."""
    return place_curves(t.keypoints, t.dense, t.heading_rad, goal_px, resolution)


def place_curves(keypoints: np.ndarray, dense: np.ndarray, heading_rad: float, goal_px: np.ndarray,
                 resolution: float) -> tuple[np.ndarray, np.ndarray]:
    """A template's (keypoints, dense) from its own frame (metres, ending at ``keypoints[-1]``) to map pixels,
    ending on ``goal_px``, its first leg along ``heading_rad`` (see :func:`place_template`)."""
    c, s = np.cos(heading_rad), np.sin(heading_rad)
    rot = np.array([[c, -s], [s, c]])
    end = keypoints[-1]

    def move(points: np.ndarray) -> np.ndarray:
        metres = (points - end) @ rot.T
        return np.asarray(goal_px, dtype=np.float64) + np.stack([metres[:, 0], -metres[:, 1]], axis=1) / resolution

    return move(keypoints), move(dense)


def sketch_fits(costmap: Costmap, dense: np.ndarray, frame: RobotFrame, margin_px: float, clearance_px: float
                ) -> bool:
    """Whether a placed sketch's ideal curve (map pixels) fits the robot-frame window of its start, lies on the
    map and keeps ``clearance_px`` from non-free space: the checks a template passes before it is executed."""
    if not fits_robot_frame(dense, frame, margin_px):
        return False
    cells = np.rint(dense).astype(np.int64)
    h, w = costmap.grid.shape
    if (cells < 0).any() or (cells[:, 0] >= w).any() or (cells[:, 1] >= h).any():
        return False
    return bool(costmap.clearance_px[cells[:, 1], cells[:, 0]].min() >= clearance_px)
