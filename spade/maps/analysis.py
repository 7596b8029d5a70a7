"""Free-space analysis of occupancy maps: where a round robot fits, and how much room it has to manoeuvre."""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from spade.maps.occupancy import FREE, OccupancyMap


def traversable_mask(m: OccupancyMap, robot_radius_m: float) -> np.ndarray:
    """Cells where the centre of a disc robot of ``robot_radius_m`` can stand with its footprint on FREE cells.

    Unknown cells and the map border count as blocked (a planner must not drive into unexplored space). A cell is
    traversable when the Euclidean distance from its centre to the nearest non-free cell centre exceeds the radius
    in pixels.
    """
    if not robot_radius_m >= 0.0:
        raise ValueError(f"robot_radius_m must be >= 0, got {robot_radius_m}")
    free = np.pad(m.grid == FREE, 1, constant_values=False)
    dist = ndimage.distance_transform_edt(free)[1:-1, 1:-1]
    return dist > robot_radius_m / m.resolution


def largest_free_component(m: OccupancyMap, robot_radius_m: float = 0.0) -> np.ndarray:
    """Boolean mask of the largest 8-connected component of ``traversable_mask(m, robot_radius_m)``.

    All False when nothing is traversable.
    """
    mask = traversable_mask(m, robot_radius_m)
    labels, n = ndimage.label(mask, structure=np.ones((3, 3), dtype=bool))
    if n == 0:
        return np.zeros_like(mask)
    sizes = np.bincount(labels.reshape(-1), minlength=n + 1)
    sizes[0] = 0
    return labels == int(np.argmax(sizes))


def clear_square_fits(mask: np.ndarray, side_px: int) -> bool:
    """Whether an axis-aligned ``side_px`` x ``side_px`` window of all-True cells exists in ``mask``."""
    if side_px < 1:
        raise ValueError(f"side_px must be >= 1, got {side_px}")
    h, w = mask.shape
    if side_px > h or side_px > w:
        return False
    sat = np.zeros((h + 1, w + 1), dtype=np.int64)
    sat[1:, 1:] = np.cumsum(np.cumsum(mask, axis=0, dtype=np.int64), axis=1)
    s = side_px
    window = sat[s:, s:] - sat[:-s, s:] - sat[s:, :-s] + sat[:-s, :-s]
    return bool((window == s * s).any())


def max_clear_square_m(m: OccupancyMap, robot_radius_m: float = 0.22) -> float:
    """Side (metres) of the largest axis-aligned square inside the largest traversable component.

    The robot's centre can visit every point of such a square with its whole footprint on free cells, so any
    sketch (L or U manoeuvre) that fits in the square can be driven. Binary search over the side length.
    """
    comp = largest_free_component(m, robot_radius_m)
    lo, hi = 0, min(comp.shape)
    while lo < hi:
        mid = (lo + hi + 1) // 2
        if clear_square_fits(comp, mid):
            lo = mid
        else:
            hi = mid - 1
    return lo * m.resolution
