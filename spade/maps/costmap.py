"""The inflated costmap of an occupancy grid, as Nav2's inflation layer builds it for a round robot.

Cells closer to an obstacle than the robot radius are lethal, and a cost that decays exponentially with the
distance to obstacles pushes a minimum-cost path away from walls. The annotation tool drives sketches on it
(:mod:`spade.annotation.execution`), the metrics' shortest-path baseline and the planner's path decoding
search on it (:mod:`spade.metrics.baselines`, :mod:`spade.metrics.decoding`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np
from scipy import ndimage

from spade.maps.occupancy import FREE


@dataclass(frozen=True)
class Costmap:
    """Inflated costmap of one map, computed once per map.

    ``clearance_px``: Euclidean distance (pixels) from each free cell to the nearest non-free cell (unknown
    counts as non-free, as for Nav2 with ``track_unknown_space``), 0 on non-free cells.
    ``cost``: per-cell traversal cost for the planner, ``inf`` where the robot's centre may not go.
    """

    grid: np.ndarray
    resolution: float
    clearance_px: np.ndarray
    cost: np.ndarray
    robot_radius_px: float


def build_costmap(grid: np.ndarray, resolution: float, robot: Mapping[str, Any],
                  cost_weight: float) -> Costmap:
    """Inflate ``grid`` (uint8 codes) for a round robot.

    ``robot`` holds ``radius_m`` (inscribed radius: lethal closer than this), ``inflation_radius_m`` (no extra
    cost beyond it) and ``cost_scaling_factor`` (Nav2's exponential decay rate, 1/m). The planner's cost of a
    cell is ``1 + cost_weight * exp(-scaling * (d - radius))`` inside the inflation radius, 1 beyond.
    """
    grid = np.asarray(grid)
    if grid.ndim != 2 or grid.dtype != np.uint8:
        raise ValueError(f"grid must be a 2-D uint8 array of occupancy codes, got {grid.dtype} {grid.shape}")
    free = grid == FREE
    clearance = ndimage.distance_transform_edt(free).astype(np.float32)
    d_m = clearance * resolution
    radius = float(robot["radius_m"])
    inflation = float(robot["inflation_radius_m"])
    scaling = float(robot["cost_scaling_factor"])
    decay = np.exp(-scaling * np.clip(d_m - radius, 0.0, None))
    cost = (1.0 + cost_weight * np.where(d_m <= inflation, decay, 0.0)).astype(np.float64)
    cost[d_m < radius] = np.inf
    cost[~free] = np.inf
    return Costmap(grid, float(resolution), clearance, cost, radius / resolution)
