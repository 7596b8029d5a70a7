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
