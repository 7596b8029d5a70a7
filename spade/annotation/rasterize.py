"""Rasterisation of robot states along an executed path into the four instance images.

The window is axis-aligned with the map (as Nav2's rolling local costmap is), so a robot state only decides
where the window lies, never how it is rotated. Everything is in pixels: map pixel coordinates in, window
pixel coordinates (x = column, y = row) out.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from skimage.draw import disk, line
from skimage.morphology import thin

from spade.data.polyline import resample_polyline

UNKNOWN_CODE = 0  # spade.maps.UNKNOWN: cells outside the map read as unknown, as in a rolling costmap


@dataclass(frozen=True)
class Instance:
    """One demonstration: the window's occupancy codes, start/goal discs, path curve and polyline."""

    occupancy: np.ndarray  # (S, S) uint8 codes
    start: np.ndarray  # (S, S) bool
    goal: np.ndarray  # (S, S) bool
    path: np.ndarray  # (S, S) bool
    waypoints: np.ndarray  # (K, 2) float32, window pixel coords
    origin: tuple[int, int]  # window's top-left cell in the map, (col, row)


def crop(grid: np.ndarray, col0: int, row0: int, size: int) -> np.ndarray:
    """``size`` x ``size`` window of ``grid`` with top-left cell (col0, row0); outside the map is unknown."""
    out = np.full((size, size), UNKNOWN_CODE, dtype=np.uint8)
    h, w = grid.shape
    r0, r1 = max(row0, 0), min(row0 + size, h)
    c0, c1 = max(col0, 0), min(col0 + size, w)
    if r0 < r1 and c0 < c1:
        out[r0 - row0:r1 - row0, c0 - col0:c1 - col0] = grid[r0:r1, c0:c1]
    return out


def draw_curve(points: np.ndarray, size: int) -> np.ndarray:
    """One 8-connected, one-pixel-wide curve through ``points`` (window pixel coords) on a size x size canvas.

    Successive points are joined with Bresenham lines (``skimage.draw.line``), which makes the curve
    8-connected; ``skimage.morphology.thin`` then removes the redundant corner pixels of staircases.
    """
    cells = np.rint(points).astype(np.int64)
    canvas = np.zeros((size, size), dtype=bool)
    if len(cells) == 1:
        canvas[cells[0, 1], cells[0, 0]] = True
        return canvas
    for (c0, r0), (c1, r1) in zip(cells[:-1], cells[1:]):
        rr, cc = line(int(r0), int(c0), int(r1), int(c1))
        canvas[rr, cc] = True
    return thin(canvas)


def fits(points: np.ndarray, size: int, margin_px: float) -> bool:
    """Whether the points' bounding box plus ``margin_px`` on every side fits in a size x size window."""
    span = points.max(axis=0) - points.min(axis=0)
    return bool((span + 2 * margin_px <= size - 1).all())


def place_window(points: np.ndarray, size: int, margin_px: float, rng: np.random.Generator) -> tuple[int, int]:
    """Random integer top-left (col0, row0) such that all points lie ``margin_px`` inside the window."""
    lo = np.ceil(points.max(axis=0) + margin_px - (size - 1)).astype(np.int64)
    hi = np.floor(points.min(axis=0) - margin_px).astype(np.int64)
    if (lo > hi).any():
        raise ValueError(f"points spanning {points.max(axis=0) - points.min(axis=0)} px do not fit in a {size} px "
                         f"window with a {margin_px} px margin")
    col0 = int(rng.integers(lo[0], hi[0] + 1))
    row0 = int(rng.integers(lo[1], hi[1] + 1))
    return col0, row0


def state_indices(n_points: int, step_px: float, spacing_px: float, min_remaining_px: float) -> np.ndarray:
    """Indices of robot states every ``spacing_px`` along a path of ``n_points`` spaced ``step_px``, leaving at
    least ``min_remaining_px`` of path to drive."""
    length = (n_points - 1) * step_px
    last = length - min_remaining_px
    if last < 0:
        return np.zeros(0, dtype=np.int64)
    arc = np.arange(0.0, last + 1e-9, spacing_px)
    return np.unique(np.rint(arc / step_px).astype(np.int64))


def render(occupancy: np.ndarray, local: np.ndarray, disc_radius_px: float, num_waypoints: int,
           origin: tuple[int, int] = (0, 0)) -> Instance:
    """Instance from a window's occupancy codes and the remaining path in window pixel coordinates."""
    size = occupancy.shape[0]
    path = draw_curve(local, size)
    start = np.zeros((size, size), dtype=bool)
    goal = np.zeros((size, size), dtype=bool)
    for canvas, (x, y) in ((start, local[0]), (goal, local[-1])):
        rr, cc = disk((round(y), round(x)), max(disc_radius_px, 0.5) + 0.5, shape=(size, size))
        canvas[rr, cc] = True
    waypoints = resample_polyline(local, num_waypoints).astype(np.float32)
    return Instance(occupancy, start, goal, path, waypoints, origin)


def make_instance(grid: np.ndarray, remaining: np.ndarray, size: int, margin_px: float, disc_radius_px: float,
                  num_waypoints: int, rng: np.random.Generator) -> Instance:
    """Rasterise the state 'robot at remaining[0], goal at remaining[-1]' into a randomly placed window of
    ``grid`` (map pixel coordinates)."""
    col0, row0 = place_window(remaining, size, margin_px, rng)
    local = remaining - np.array([col0, row0], dtype=np.float64)
    return render(crop(grid, col0, row0, size), local, disc_radius_px, num_waypoints, (col0, row0))
