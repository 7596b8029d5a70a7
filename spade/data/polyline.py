"""Polyline helpers shared by the annotation tool, the dataset and the metrics."""

from __future__ import annotations

import numpy as np


def polyline_length(points: np.ndarray) -> float:
    """Total arc length of an (N, 2) polyline."""
    pts = np.asarray(points, dtype=np.float64)
    if len(pts) < 2:
        return 0.0
    return float(np.linalg.norm(np.diff(pts, axis=0), axis=1).sum())


def resample_polyline(points: np.ndarray, k: int) -> np.ndarray:
    """Resample an (N, 2) polyline to ``k`` points evenly spaced by arc length.

    The first and last points are kept exactly. Repeated consecutive points are harmless. A single point (or a
    polyline of zero length) is repeated ``k`` times.
    """
    if k < 1:
        raise ValueError(f"resample_polyline needs k >= 1, got {k}")
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) == 0:
        raise ValueError(f"resample_polyline expects an (N, 2) array with N >= 1, got shape {pts.shape}")
    seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    total = cum[-1]
    if total <= 0.0:
        return np.repeat(pts[:1], k, axis=0)
    if k == 1:
        return pts[:1].copy()
    targets = np.linspace(0.0, total, k)
    x = np.interp(targets, cum, pts[:, 0])
    y = np.interp(targets, cum, pts[:, 1])
    out = np.stack([x, y], axis=1)
    out[0], out[-1] = pts[0], pts[-1]
    return out


def smooth_path(points: np.ndarray, smoothing_px: float, step_px: float, simplify_px: float = 0.0) -> np.ndarray:
    """Smooth a grid path and resample it evenly every ``step_px``; both ends are kept exactly.

    An 8-connected grid path runs along 0/45-degree staircases; Douglas-Peucker simplification
    (``skimage.measure.approximate_polygon``, tolerance ``simplify_px``) first straightens them (what a
    Nav2 planner's path smoother does), then a parametric spline (scipy ``splprep``, smoothing
    ``s = N * smoothing_px**2`` over the path resampled every pixel) rounds the corners.
    """
    from scipy import interpolate  # here, so that readers of the dataset format do not load scipy
    from skimage.measure import approximate_polygon

    pts = np.asarray(points, dtype=np.float64)
    if simplify_px > 0 and len(pts) > 2:
        pts = approximate_polygon(pts, tolerance=simplify_px)
        pts = resample_polyline(pts, max(2, int(np.ceil(polyline_length(pts))) + 1))
    keep = np.concatenate([[True], np.linalg.norm(np.diff(pts, axis=0), axis=1) > 1e-9])
    pts = pts[keep]
    length = polyline_length(pts)
    n_out = max(2, int(np.ceil(length / step_px)) + 1)
    if len(pts) < 4:
        return resample_polyline(pts, n_out)
    seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    u = np.concatenate([[0.0], np.cumsum(seg)]) / length
    weights = np.ones(len(pts))
    weights[[0, -1]] = 100.0  # pin the start and the goal
    tck, _ = interpolate.splprep([pts[:, 0], pts[:, 1]], u=u, w=weights, s=len(pts) * smoothing_px ** 2, k=3)
    fine = np.stack(interpolate.splev(np.linspace(0.0, 1.0, 4 * n_out), tck), axis=1)
    fine[0], fine[-1] = pts[0], pts[-1]
    return resample_polyline(fine, max(2, int(np.ceil(polyline_length(fine) / step_px)) + 1))
