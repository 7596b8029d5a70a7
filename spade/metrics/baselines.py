"""Classical predictors that learn nothing, scored with the same metrics as the models on the same instances.

A learned planner is worth deploying only where it beats these on the operator's preference (DESIGN.md section 5):

- ``straight``: the straight line from the start to the goal;
- ``shortest``: the minimum-cost path on the window's inflated costmap, what a Nav2-style global planner would
  drive (the annotation tool's costmap and grid planner, :mod:`spade.annotation.execution`, with the
  TurtleBot3 footprint and Nav2's default inflation, then its smoothing);
- ``heading``: a template that knows only the robot's heading: straight ahead to the goal's projection on the
  heading line, then a 90 degree turn to the goal (in the robot frame the heading is "up the image").

Each predictor gives a polyline in window pixel coordinates; :func:`baseline_images` draws them as one-pixel
probability images, which go through the same extraction, APE, Hd19 and FID as a model's prediction.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import torch
from skimage.graph import MCP_Geometric

from spade.metrics.extraction import marker_centre

BASELINES: tuple[str, ...] = ("straight", "shortest", "heading")
"""Names of the baselines, as used in metric keys (``test/baseline/<name>/ape_cm``)."""

NAV2_ROBOT: dict[str, float] = {"radius_m": 0.105, "inflation_radius_m": 0.55, "cost_scaling_factor": 3.0}
"""The annotation tool's defaults (conf/annotate.yaml): TurtleBot3 Burger with Nav2's inflation layer."""
NAV2_COST_WEIGHT = 4.0
HEADING_UP = np.array([0.0, -1.0])  # the robot frame's heading in window pixel coordinates


def straight_line(start: np.ndarray, goal: np.ndarray) -> np.ndarray:
    """The segment from ``start`` to ``goal`` (x, y)."""
    return np.stack([np.asarray(start, np.float64), np.asarray(goal, np.float64)])


def heading_template(start: np.ndarray, goal: np.ndarray, heading: np.ndarray = HEADING_UP) -> np.ndarray:
    """Straight along ``heading`` to the goal's projection on the heading line, then a right angle to the goal."""
    start, goal = np.asarray(start, np.float64), np.asarray(goal, np.float64)
    h = np.asarray(heading, np.float64) / np.linalg.norm(heading)
    corner = start + h * float(np.dot(goal - start, h))
    return np.stack([start, corner, goal])


def shortest_path(occupancy: np.ndarray, start: np.ndarray, goal: np.ndarray, resolution: float,
                  robot: Mapping[str, Any] = NAV2_ROBOT, cost_weight: float = NAV2_COST_WEIGHT) -> np.ndarray | None:
    """Minimum-cost path from ``start`` to ``goal`` on the inflated costmap of ``occupancy`` (uint8 codes), smoothed
    as the annotation tool smooths executions; None when the goal cannot be reached.

    Cells closer to an obstacle than the robot radius are lethal for a global planner; a robot already inside that
    band (a window rotated next to a wall) may still drive out of it, so those cells cost a lot but are not
    forbidden here; obstacles and unknown cells are.
    """
    from spade.annotation.execution import build_costmap, smooth_path

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


def baseline_polylines(state: np.ndarray, resolution: float) -> dict[str, np.ndarray | None]:
    """Each baseline's polyline (window pixels) for one state (3, H, W): occupancy ``code * 0.5``, start, goal."""
    start = marker_centre(state[1], "start")
    goal = marker_centre(state[2], "goal")
    codes = np.rint(np.asarray(state[0], dtype=np.float64) * 2).astype(np.uint8)
    return {
        "straight": straight_line(start, goal),
        "shortest": shortest_path(codes, start, goal, resolution),
        "heading": heading_template(start, goal),
    }


def draw_polyline(points: np.ndarray | None, height: int, width: int) -> np.ndarray:
    """A (H, W) float32 image with 1 on the polyline's one-pixel curve (empty for None)."""
    from spade.annotation.rasterize import draw_curve

    image = np.zeros((height, width), dtype=np.float32)
    if points is None or len(points) == 0:
        return image
    side = max(height, width)
    pts = np.clip(np.asarray(points, np.float64), 0, [width - 1, height - 1])
    image[:] = draw_curve(pts, side)[:height, :width]
    return image


@torch.no_grad()
def baseline_images(state: torch.Tensor, resolution: torch.Tensor | float) -> dict[str, torch.Tensor]:
    """Each baseline's prediction (B, 1, H, W) in {0, 1} for a batch of states (B, 3, H, W)."""
    s = state.detach().float().cpu().numpy()
    b, _, h, w = s.shape
    res = np.broadcast_to(np.asarray(resolution.cpu() if isinstance(resolution, torch.Tensor) else resolution,
                                     dtype=np.float64).reshape(-1), (b,))
    out = {name: np.zeros((b, 1, h, w), dtype=np.float32) for name in BASELINES}
    for i in range(b):
        for name, poly in baseline_polylines(s[i], float(res[i])).items():
            out[name][i, 0] = draw_polyline(poly, h, w)
    return {name: torch.from_numpy(img).to(state.device) for name, img in out.items()}
