"""Classical predictors that learn nothing, scored with the same metrics as the models on the same instances.

A learned planner is worth deploying only where it beats these on the operator's preference:

- ``straight``: the straight line from the start to the goal;
- ``shortest``: the minimum-cost path on the window's inflated costmap, what a Nav2-style global planner would
  drive (the annotation tool's costmap and grid planner, :mod:`spade.maps.costmap`, with the
  TurtleBot3 footprint and Nav2's default inflation, then its smoothing);
- ``heading``: a shape template that knows only the robot's heading and the instance's shape label. For an L
  (and any other label): straight ahead to the goal's projection on the heading line, then a 90 degree turn to
  the goal (in the robot frame the heading is "up the image"). For a U (:func:`u_template`): straight ahead, a
  half turn whose radius meets the goal's line, and straight back to the goal. The turn starts abreast of the
  goal (:data:`U_TAIL_M` = 0): most windows start part-way along a demonstrated U (on its leg, mid-turn or on
  the way back), so a longer way back overshoots. On 150 training instances of the transfer preset at
  ``scale=cpu`` the mean distance to the demonstration was 29.4 / 30.9 / 32.7 / 40.7 / 61.5 cm for a way back
  of 0 / 0.2 / 0.3 / 0.6 / 1.2 m (the annotation presets' mean U tail, 1.2 m, was this template's first
  setting: 55.1 cm APE on the cpu-scale U transfer test, worse than the straight line's 49.7; now 28.75 cm).
  An L template degenerates on U test sets too (48.9 cm there), so every U instance gets the U template.

Each predictor gives a polyline in window pixel coordinates; :func:`baseline_images` draws them as one-pixel
probability images, which go through the same extraction, APE, Hd19 and FID as a model's prediction.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import torch
from skimage.graph import MCP_Geometric

from spade.data.rasterize import draw_polyline  # noqa: F401  (drawn here, imported from here by others)
from spade.metrics.extraction import marker_centre
from spade.data.polyline import smooth_path
from spade.maps.costmap import build_costmap

BASELINES: tuple[str, ...] = ("straight", "shortest", "heading")
"""Names of the baselines, as used in metric keys (``test/baseline/<name>/ape_cm``)."""
NAV2_ROBOT: dict[str, float] = {"radius_m": 0.105, "inflation_radius_m": 0.55, "cost_scaling_factor": 3.0}
"""The annotation tool's defaults (conf/annotate.yaml): TurtleBot3 Burger with Nav2's inflation layer."""
NAV2_COST_WEIGHT = 4.0
HEADING_UP = np.array([0.0, -1.0])  # the robot frame's heading in window pixel coordinates
U_TAIL_M = 0.0
"""The U template's way back beyond the goal's projection (metres); chosen on training instances (module doc)."""


def straight_line(start: np.ndarray, goal: np.ndarray) -> np.ndarray:
    """The segment from ``start`` to ``goal`` (x, y)."""
    return np.stack([np.asarray(start, np.float64), np.asarray(goal, np.float64)])


def heading_template(start: np.ndarray, goal: np.ndarray, heading: np.ndarray = HEADING_UP) -> np.ndarray:
    """Straight along ``heading`` to the goal's projection on the heading line, then a right angle to the goal."""
    start, goal = np.asarray(start, np.float64), np.asarray(goal, np.float64)
    h = np.asarray(heading, np.float64) / np.linalg.norm(heading)
    corner = start + h * float(np.dot(goal - start, h))
    return np.stack([start, corner, goal])


def u_template(start: np.ndarray, goal: np.ndarray, resolution: float, tail_m: float = U_TAIL_M,
               heading: np.ndarray = HEADING_UP, window: tuple[int, int] | None = None,
               step_deg: float = 10.0) -> np.ndarray:
    """Straight along ``heading``, a half turn of radius half the goal's lateral offset, straight back to the goal.

    The turn starts ``tail_m`` beyond the goal's projection on the heading line (never behind the robot), and no
    higher than the window's top edge allows (``window`` (H, W)). A goal straight ahead (lateral offset under a
    pixel) gives the straight line.
    """
    start, goal = np.asarray(start, np.float64), np.asarray(goal, np.float64)
    h = np.asarray(heading, np.float64) / np.linalg.norm(heading)
    side = np.array([-h[1], h[0]])  # heading rotated by +90 degrees in pixel coordinates (right of "up")
    rel = goal - start
    ahead, lateral = float(np.dot(rel, h)), float(np.dot(rel, side))
    if abs(lateral) < 1.0:
        return straight_line(start, goal)
    radius = abs(lateral) / 2.0
    leg = max(ahead, 0.0) + tail_m / resolution
    if window is not None:  # keep the top of the turn inside the window (the heading is "up the image")
        leg = min(leg, max(float(np.dot(start, -h)) - radius, max(ahead, 0.0)))
    leg = max(leg, max(ahead, 0.0))
    turn_start = start + h * leg
    centre = turn_start + side * np.sign(lateral) * radius
    phi = np.deg2rad(np.arange(0.0, 180.0 + 1e-9, step_deg))
    # from the turn start (angle 0) over the top to the point abreast the goal (angle 180 degrees)
    across = side * np.sign(lateral) * radius
    arc = centre[None] - np.cos(phi)[:, None] * across[None] + np.sin(phi)[:, None] * (h * radius)[None]
    if np.linalg.norm(arc[-1] - goal) < 1e-6:  # no way back (the turn ends at the goal): no repeated point
        arc = arc[:-1]
    return np.vstack([start, arc, goal])


def shortest_path(occupancy: np.ndarray, start: np.ndarray, goal: np.ndarray, resolution: float,
                  robot: Mapping[str, Any] = NAV2_ROBOT, cost_weight: float = NAV2_COST_WEIGHT) -> np.ndarray | None:
    """Minimum-cost path from ``start`` to ``goal`` on the inflated costmap of ``occupancy`` (uint8 codes), smoothed
    as the annotation tool smooths executions; None when the goal cannot be reached.

    Cells closer to an obstacle than the robot radius are lethal for a global planner; a robot already inside that
    band (a window rotated next to a wall) may still drive out of it, so those cells cost a lot but are not
    forbidden here; obstacles and unknown cells are.
    """
    costmap = build_costmap(np.ascontiguousarray(occupancy, dtype=np.uint8), resolution, robot, cost_weight)
    cost = costmap.cost.copy()
    free = costmap.grid == 1
    cost[free & ~np.isfinite(cost)] = 1.0 + 10.0 * cost_weight
    cost[~free] = np.inf
    h, w = cost.shape
    a = np.clip(np.rint(np.asarray(start)[::-1]).astype(int), 0, [h - 1, w - 1])
    b = np.clip(np.rint(np.asarray(goal)[::-1]).astype(int), 0, [h - 1, w - 1])
    for cell in (a, b):  # a disc centre on a non-free pixel: plan from it anyway
        if not np.isfinite(cost[tuple(cell)]):
            cost[tuple(cell)] = 1.0 + 10.0 * cost_weight
    mcp = MCP_Geometric(cost, fully_connected=True)
    cum, _ = mcp.find_costs([tuple(a)], [tuple(b)], find_all_ends=True)
    if not np.isfinite(cum[tuple(b)]):
        return None
    rc = np.asarray(mcp.traceback(tuple(b)), dtype=np.float64)
    pts = rc[:, ::-1]
    if len(pts) < 2:
        return straight_line(start, goal)
    return smooth_path(pts, smoothing_px=1.0, step_px=0.5, simplify_px=1.5)


def shape_template(start: np.ndarray, goal: np.ndarray, resolution: float, shape: str | None = None,
                   window: tuple[int, int] | None = None) -> np.ndarray:
    """The heading template of the instance's shape: :func:`u_template` for ``U``, :func:`heading_template` else."""
    if shape == "U":
        return u_template(start, goal, resolution, window=window)
    return heading_template(start, goal)


def baseline_polylines(state: np.ndarray, resolution: float, shape: str | None = None
                       ) -> dict[str, np.ndarray | None]:
    """Each baseline's polyline (window pixels) for one state (3, H, W): occupancy ``code * 0.5``, start, goal;
    ``shape`` is the instance's label (``L``, ``U``; it picks the template)."""
    start = marker_centre(state[1], "start")
    goal = marker_centre(state[2], "goal")
    codes = np.rint(np.asarray(state[0], dtype=np.float64) * 2).astype(np.uint8)
    return {
        "straight": straight_line(start, goal),
        "shortest": shortest_path(codes, start, goal, resolution),
        "heading": shape_template(start, goal, resolution, shape, window=codes.shape),
    }


def batch_baseline_polylines(state: torch.Tensor, resolution: torch.Tensor | float,
                             shapes: list[str] | None = None) -> dict[str, list[np.ndarray | None]]:
    """Each baseline's polylines (one per instance, None where it has none) for a batch of states (B, 3, H, W)."""
    s = state.detach().float().cpu().numpy()
    b = s.shape[0]
    res = np.broadcast_to(np.asarray(resolution.cpu() if isinstance(resolution, torch.Tensor) else resolution,
                                     dtype=np.float64).reshape(-1), (b,))
    out: dict[str, list[np.ndarray | None]] = {name: [] for name in BASELINES}
    for i in range(b):
        shape = shapes[i] if shapes is not None else None
        for name, poly in baseline_polylines(s[i], float(res[i]), shape).items():
            out[name].append(poly)
    return out


def draw_polylines(polylines: list[np.ndarray | None], height: int, width: int,
                   device: torch.device | str = "cpu") -> torch.Tensor:
    """(B, 1, H, W) float32 images of polylines drawn as a dataset's path channel (:func:`draw_polyline`)."""
    images = np.zeros((len(polylines), 1, height, width), dtype=np.float32)
    for i, poly in enumerate(polylines):
        images[i, 0] = draw_polyline(poly, height, width)
    return torch.from_numpy(images).to(device)


@torch.no_grad()
def baseline_images(state: torch.Tensor, resolution: torch.Tensor | float,
                    shapes: list[str] | None = None) -> dict[str, torch.Tensor]:
    """Each baseline's prediction (B, 1, H, W) in {0, 1} for a batch of states (B, 3, H, W)."""
    _, _, h, w = state.shape
    return {name: draw_polylines(polys, h, w, state.device)
            for name, polys in batch_baseline_polylines(state, resolution, shapes).items()}
