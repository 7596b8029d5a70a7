"""Three-level occupancy grid shared by every SPADE module.

Codes are uint8: ``UNKNOWN = 0``, ``FREE = 1``, ``OCCUPIED = 2``; the network sees ``code * 0.5`` (unknown 0.0,
free 0.5, obstacle 1.0). Arrays are (rows, cols) with row 0 at the TOP of the map image, as stored in the image
file. ``origin`` is the ROS map origin: the world pose (x, y, yaw) of the lower-left corner of the bottom-left
pixel, so the bottom row of the array is the one nearest to ``origin``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

UNKNOWN: int = 0
FREE: int = 1
OCCUPIED: int = 2
CODES: tuple[int, int, int] = (UNKNOWN, FREE, OCCUPIED)

# Tolerance on resolution ratios: 0.05 / 0.02 is 2.5000000000000004 in binary floating point.
_EPS = 1e-9


def _check_resolution(resolution: float, what: str) -> float:
    try:
        value = float(resolution)
    except (TypeError, ValueError):
        raise ValueError(f"{what} must be a number of metres per pixel, got {resolution!r}") from None
    if not math.isfinite(value) or value <= 0.0:
        raise ValueError(f"{what} must be a finite number > 0 (metres per pixel), got {resolution!r}")
    return value


@dataclass
class OccupancyMap:
    """A 2D occupancy grid with its metric frame.

    Attributes:
        grid: (H, W) uint8 array of codes UNKNOWN / FREE / OCCUPIED.
        resolution: metres per pixel (> 0).
        origin: (x, y, yaw) of the lower-left corner of the bottom-left pixel, as in a ROS map yaml.
        name: a short identifier (file stem for loaded maps, ``kind_seed`` for generated ones).
        costs: optional (H, W) int8 array of ``nav_msgs/OccupancyGrid`` values (-1 unknown, 0..100) kept by
            ``load_ros_map`` for ``mode: scale`` and ``mode: raw`` maps, whose in-between values the three-level
            ``grid`` cannot hold. ``None`` otherwise; operations that change the grid geometry drop it.
    """

    grid: np.ndarray
    resolution: float
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)
    name: str = "map"
    costs: np.ndarray | None = field(default=None, repr=False, compare=False)

    def __post_init__(self) -> None:
        grid = np.asarray(self.grid)
        if grid.ndim != 2 or grid.shape[0] == 0 or grid.shape[1] == 0:
            raise ValueError(f"OccupancyMap.grid must be a non-empty 2D (H, W) array, got shape {grid.shape}")
        if grid.dtype != np.uint8:
            if not np.issubdtype(grid.dtype, np.integer) and grid.dtype != np.bool_:
                raise ValueError(
                    f"OccupancyMap.grid must hold integer codes (uint8 UNKNOWN=0/FREE=1/OCCUPIED=2), got {grid.dtype}"
                )
            grid = grid.astype(np.uint8)
        if grid.max() > OCCUPIED:
            bad = np.unique(grid[grid > OCCUPIED])[:5].tolist()
            raise ValueError(
                f"OccupancyMap.grid holds values {bad} outside the codes UNKNOWN=0, FREE=1, OCCUPIED=2; "
                "convert image intensities with load_ros_map or map them to codes first"
            )
        self.grid = np.ascontiguousarray(grid)
        self.resolution = _check_resolution(self.resolution, "OccupancyMap.resolution")
        origin = tuple(float(v) for v in np.asarray(self.origin, dtype=np.float64).reshape(-1))
        if len(origin) != 3 or not all(math.isfinite(v) for v in origin):
            raise ValueError(f"OccupancyMap.origin must be three finite numbers (x, y, yaw), got {self.origin!r}")
        self.origin = origin  # type: ignore[assignment]
        if self.costs is not None:
            costs = np.asarray(self.costs)
            if costs.shape != grid.shape:
                raise ValueError(f"OccupancyMap.costs shape {costs.shape} differs from grid shape {grid.shape}")
            self.costs = costs.astype(np.int8, copy=False)

    # ----------------------------------------------------------------- geometry
    @property
    def height(self) -> int:
        """Number of rows (H)."""
        return int(self.grid.shape[0])

    @property
    def width(self) -> int:
        """Number of columns (W)."""
        return int(self.grid.shape[1])

    @property
    def size_m(self) -> tuple[float, float]:
        """(width, height) of the map in metres."""
        return self.width * self.resolution, self.height * self.resolution

    def _require_axis_aligned(self) -> None:
        if abs(self.origin[2]) > 1e-12:
            raise ValueError(
                f"map {self.name!r} has origin yaw {self.origin[2]} rad; world<->pixel conversion supports only "
                "yaw 0 (rotate the map image and set the yaml origin yaw to 0)"
            )

    def world_to_pixel(self, xy: np.ndarray) -> np.ndarray:
        """Map-frame metres (..., 2) -> pixel coordinates (..., 2) as float (col, row), pixel centres at integers."""
        self._require_axis_aligned()
        pts = np.asarray(xy, dtype=np.float64)
        if pts.shape[-1:] != (2,):
            raise ValueError(f"world_to_pixel expects an array of shape (..., 2), got {pts.shape}")
        col = (pts[..., 0] - self.origin[0]) / self.resolution - 0.5
        row = self.height - 0.5 - (pts[..., 1] - self.origin[1]) / self.resolution
        return np.stack([col, row], axis=-1)

    def pixel_to_world(self, colrow: np.ndarray) -> np.ndarray:
        """Pixel coordinates (..., 2) as (col, row) -> map-frame metres (..., 2) (x, y)."""
        self._require_axis_aligned()
        pts = np.asarray(colrow, dtype=np.float64)
        if pts.shape[-1:] != (2,):
            raise ValueError(f"pixel_to_world expects an array of shape (..., 2), got {pts.shape}")
        x = self.origin[0] + (pts[..., 0] + 0.5) * self.resolution
        y = self.origin[1] + (self.height - 1 - pts[..., 1] + 0.5) * self.resolution
        return np.stack([x, y], axis=-1)

    # ----------------------------------------------------------------- views
    def encoded(self) -> np.ndarray:
        """Network encoding, float32 (H, W): unknown 0.0, free 0.5, obstacle 1.0."""
        return self.grid.astype(np.float32) * np.float32(0.5)

    def free_mask(self) -> np.ndarray:
        """Boolean (H, W) mask of FREE cells."""
        return self.grid == FREE

    def fractions(self) -> dict[str, float]:
        """Share of cells per class: ``{"occupied": ..., "free": ..., "unknown": ...}`` (sums to 1)."""
        counts = np.bincount(self.grid.reshape(-1), minlength=3).astype(np.float64)
        total = float(self.grid.size)
        return {
            "occupied": float(counts[OCCUPIED] / total),
            "free": float(counts[FREE] / total),
            "unknown": float(counts[UNKNOWN] / total),
        }

    # ----------------------------------------------------------------- resampling
    def resampled(self, resolution: float) -> OccupancyMap:
        """This map at another resolution (metres per pixel); the origin (lower-left corner) is kept.

        Downsampling (coarser target) partitions the source pixels: each source pixel belongs to the target cell
        that contains its centre, so each target cell gathers ``factor`` x ``factor`` source pixels on average
        (2 or 3 per axis for 0.02 -> 0.05 m/px). A target cell is
          * OCCUPIED if any of its source pixels is occupied (a 1-px wall never disappears and is not thickened
            beyond one target cell),
          * else FREE if its free pixels are at least as many as its unknown pixels,
          * else UNKNOWN (unknown only when it dominates).
        The target size is the number of cells that hold at least one source pixel centre.

        Upsampling (finer target) is nearest neighbour: a target cell takes the code of the source pixel under
        its centre; the target size is the number of cells whose centre lies on the source map.

        ``costs`` is not resampled (the result has ``costs=None``).
        """
        target = _check_resolution(resolution, "resampled(resolution)")
        factor = target / self.resolution
        if abs(factor - 1.0) < _EPS:
            return OccupancyMap(self.grid.copy(), self.resolution, self.origin, self.name)
        # Index rows from the bottom so that the lower-left corner (the origin) stays fixed.
        flipped = self.grid[::-1]
        if factor > 1.0:
            out = _downsample(flipped, factor)
        else:
            out = _upsample(flipped, factor)
        return OccupancyMap(np.ascontiguousarray(out[::-1]), target, self.origin, self.name)


def _downsample(grid: np.ndarray, factor: float) -> np.ndarray:
    """Obstacle-preserving downsampling of a bottom-up grid; see ``OccupancyMap.resampled``."""
    h, w = grid.shape
    # Target index of each source row/column: the cell holding the source pixel centre (i + 0.5).
    tr = np.floor((np.arange(h) + 0.5) / factor + _EPS).astype(np.int64)
    tc = np.floor((np.arange(w) + 0.5) / factor + _EPS).astype(np.int64)
    th, tw = int(tr[-1]) + 1, int(tc[-1]) + 1
    cell = (tr[:, None] * tw + tc[None, :]).reshape(-1)
    flat = grid.reshape(-1)
    n = th * tw
    occ = np.bincount(cell[flat == OCCUPIED], minlength=n)
    free = np.bincount(cell[flat == FREE], minlength=n)
    unk = np.bincount(cell[flat == UNKNOWN], minlength=n)
    out = np.full(n, UNKNOWN, dtype=np.uint8)
    out[free >= unk] = FREE
    out[occ > 0] = OCCUPIED
    return out.reshape(th, tw)


def _upsample(grid: np.ndarray, factor: float) -> np.ndarray:
    """Nearest-neighbour upsampling of a bottom-up grid (``factor`` = target / source resolution < 1)."""
    h, w = grid.shape
    th = max(1, int(math.ceil(h / factor - 0.5 - _EPS)))
    tw = max(1, int(math.ceil(w / factor - 0.5 - _EPS)))
    rows = np.minimum(np.floor((np.arange(th) + 0.5) * factor + _EPS).astype(np.int64), h - 1)
    cols = np.minimum(np.floor((np.arange(tw) + 0.5) * factor + _EPS).astype(np.int64), w - 1)
    return grid[rows[:, None], cols[None, :]]
