"""Per-instance geometry behind the metrics: pose error of two polylines, Hausdorff distance of two pixel sets."""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from spade.data.polyline import resample_polyline

__all__ = ["mask_hausdorff", "polyline_ape"]


def polyline_ape(pred: np.ndarray, truth: np.ndarray, num_points: int | None = None) -> float:
    """Mean Euclidean distance (input units) between two polylines resampled to the same number of points.

    Both are resampled evenly by arc length to ``num_points`` (default: the number of points of ``truth``) and
    compared pose by pose: the translation part of evo's APE without alignment, averaged.
    """
    truth = np.asarray(truth, dtype=np.float64)
    k = len(truth) if num_points is None else int(num_points)
    a = resample_polyline(pred, k)
    b = resample_polyline(truth, k)
    return float(np.linalg.norm(a - b, axis=1).mean())


def mask_hausdorff(a: np.ndarray, b: np.ndarray) -> float:
    """Symmetric Hausdorff distance (pixels) between the pixel sets of two boolean (H, W) masks.

    Exact for pixel sets: ``max(max over a of EDT-to-b, max over b of EDT-to-a)``, where EDT-to-b is the
    Euclidean distance transform of the complement of ``b``. ``inf`` when exactly one mask is empty, 0 when both
    are.
    """
    a = np.asarray(a, dtype=bool)
    b = np.asarray(b, dtype=bool)
    if a.shape != b.shape or a.ndim != 2:
        raise ValueError(f"mask_hausdorff expects two (H, W) masks of the same shape, got {a.shape} and {b.shape}")
    has_a, has_b = a.any(), b.any()
    if not has_a or not has_b:
        return 0.0 if has_a == has_b else float("inf")
    to_b = ndimage.distance_transform_edt(~b)
    to_a = ndimage.distance_transform_edt(~a)
    return float(max(to_b[a].max(), to_a[b].max()))
