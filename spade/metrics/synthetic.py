"""Synthetic L/U path rasters, plausible predictions of them and controlled degradations: the one synthetic-data
recipe of the metrics' tests and of ``python -m spade.bench`` (metrics, FID sensitivity, a large dataset to read).

Not a dataset generator (that is the annotation tool): just enough geometry to exercise the metrics and the
storage on any image size without files, deterministically by seed.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage
from skimage.draw import disk

from spade.data.polyline import resample_polyline

__all__ = ["rasterise_polyline", "synthetic_batch", "synthetic_predictions", "degrade"]


def rasterise_polyline(points: np.ndarray, shape: tuple[int, int], width: int = 1) -> np.ndarray:
    """Boolean (H, W) raster of an (N, 2) (x, y) polyline.

    ``width`` 1: one pixel per point along the line (8-connected); larger: dilated ``max(1, (width - 1) // 2)``
    times with a cross (so widths 2 and 3 both give a 3-pixel-wide line).
    """
    pts = np.asarray(points, dtype=np.float64)
    seg = np.linalg.norm(np.diff(pts, axis=0), axis=1).sum()
    dense = resample_polyline(pts, max(2, int(np.ceil(seg * 4)) + 1))
    cols = np.clip(np.rint(dense[:, 0]).astype(int), 0, shape[1] - 1)
    rows = np.clip(np.rint(dense[:, 1]).astype(int), 0, shape[0] - 1)
    out = np.zeros(shape, dtype=bool)
    out[rows, cols] = True
    if width > 1:
        out = ndimage.binary_dilation(out, iterations=(width - 1) // 2 or 1)
    return out


def _template(shape: str, rng: np.random.Generator) -> np.ndarray:
    """Corner points of an L or U in a unit-ish local frame, first point at the origin."""
    a = rng.uniform(0.5, 1.0)
    b = rng.uniform(0.4, 0.9)
    side = rng.choice([-1.0, 1.0])
    if shape == "L":
        return np.array([[0.0, 0.0], [a, 0.0], [a, side * b]])
    if shape == "U":
        back = rng.uniform(0.3, a)
        return np.array([[0.0, 0.0], [a, 0.0], [a, side * b], [a - back, side * b]])
    raise ValueError(f"unknown shape {shape!r}; use 'L' or 'U'")


def synthetic_batch(
    n: int,
    size: int = 64,
    num_points: int = 32,
    seed: int = 0,
    width: int = 1,
    marker_radius: float = 2.0,
    resolution: float = 0.05,
    shapes: tuple[str, ...] = ("L", "U"),
) -> dict[str, np.ndarray]:
    """``n`` random L/U paths in ``size`` x ``size`` images, in the dataset's batch layout (numpy).

    Returns state (n, 3, H, W) float32 [occupancy all free (0.5), start disc, goal disc], path (n, 1, H, W)
    float32 {0, 1}, waypoints (n, num_points, 2) float64 (x, y), resolution (n,) float64.
    """
    rng = np.random.default_rng(seed)
    margin = 3.0 + marker_radius
    state = np.zeros((n, 3, size, size), dtype=np.float32)
    state[:, 0] = 0.5
    path = np.zeros((n, 1, size, size), dtype=np.float32)
    waypoints = np.zeros((n, num_points, 2), dtype=np.float64)
    for i in range(n):
        corners = _template(shapes[i % len(shapes)], rng)
        theta = rng.uniform(0, 2 * np.pi)
        rot = np.array([[np.cos(theta), -np.sin(theta)], [np.sin(theta), np.cos(theta)]])
        pts = corners @ rot.T
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        span = (size - 1 - 2 * margin) / max((hi - lo).max(), 1e-9)
        pts = (pts - lo) * span * rng.uniform(0.6, 1.0)
        room = (size - 1 - 2 * margin) - (pts.max(axis=0))
        pts = pts + margin + rng.uniform(0, 1, 2) * np.maximum(room, 0)
        waypoints[i] = resample_polyline(pts, num_points)
        path[i, 0] = rasterise_polyline(pts, (size, size), width)
        for ch, (x, y) in ((1, pts[0]), (2, pts[-1])):
            rr, cc = disk((y, x), marker_radius + 0.5, shape=(size, size))
            state[i, ch, rr, cc] = 1.0
    return {"state": state, "path": path, "waypoints": waypoints, "resolution": np.full(n, resolution)}


def synthetic_predictions(paths: np.ndarray, seed: int = 0) -> np.ndarray:
    """Plausible soft predictions of (n, 1, H, W) ground-truth path images, as a trained student's look.

    Each is blurred (sigma 0.8), shifted by a random sub-pixel offset (sigma 0.7 px), scaled to a peak of 0.95 with
    Gaussian noise (sigma 0.03) and clipped to [0, 1]; then 10 % get stray blobs, 5 % lose a tenth of their path
    pixels, and 2 % are empty (nothing predicted). Float32, deterministic by ``seed``.
    """
    paths = np.asarray(paths, dtype=np.float32)
    n = len(paths)
    rng = np.random.default_rng(seed)
    pred = np.empty_like(paths)
    for i in range(n):
        img = ndimage.gaussian_filter(paths[i, 0], 0.8)
        img = ndimage.shift(img, rng.normal(0, 0.7, 2), order=1)
        pred[i, 0] = np.clip(img / max(img.max(), 1e-6) * 0.95 + rng.normal(0, 0.03, img.shape), 0, 1)
    blobs = rng.random(n) < 0.10
    pred[blobs] = np.maximum(pred[blobs], degrade(np.zeros_like(pred[blobs]), "blobs", 1, seed=seed + 1))
    gaps = rng.random(n) < 0.05
    pred[gaps] = degrade(pred[gaps], "dropout", 0.1, seed=seed + 2)
    pred[rng.random(n) < 0.02] = 0.0
    return pred


def degrade(paths: np.ndarray, kind: str, level: float, seed: int = 0) -> np.ndarray:
    """Degraded copies of (n, 1, H, W) path images in [0, 1], for sensitivity tests.

    kind: "shift" (translate each by ``level`` pixels in a random direction), "blur" (Gaussian, sigma=``level``,
    peak rescaled to 1), "dropout" (erase a fraction ``level`` of the path pixels, in 3x3 chunks), "blobs" (add
    ``round(level)`` filled discs of radius 2 at random places).
    """
    rng = np.random.default_rng(seed)
    out = np.asarray(paths, dtype=np.float32).copy()
    n, _, h, w = out.shape
    if level == 0:
        return out
    for i in range(n):
        img = out[i, 0]
        if kind == "shift":
            ang = rng.uniform(0, 2 * np.pi)
            img[...] = ndimage.shift(img, (level * np.sin(ang), level * np.cos(ang)), order=1, mode="constant")
        elif kind == "blur":
            blurred = ndimage.gaussian_filter(img, level)
            img[...] = blurred / max(blurred.max(), 1e-9)
        elif kind == "dropout":
            rows, cols = np.nonzero(img > 0.5)
            k = int(round(level * len(rows) / 3))
            pick = rng.choice(len(rows), size=min(k, len(rows)), replace=False)
            hole = np.zeros_like(img, dtype=bool)
            hole[rows[pick], cols[pick]] = True
            img[ndimage.binary_dilation(hole)] = 0.0
        elif kind == "blobs":
            for _ in range(int(round(level))):
                rr, cc = disk((rng.uniform(0, h), rng.uniform(0, w)), 2.0, shape=(h, w))
                img[rr, cc] = 1.0
        else:
            raise ValueError(f"unknown degradation {kind!r}; use shift, blur, dropout or blobs")
    return out
