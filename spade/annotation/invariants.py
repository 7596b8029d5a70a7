"""Invariants every annotated instance must satisfy; used by the tests and handy to audit imported data."""

from __future__ import annotations

import numpy as np
from scipy import ndimage

FREE_CODE = 1
EIGHT = np.ones((3, 3), dtype=bool)


def instance_problems(occupancy: np.ndarray, start: np.ndarray, goal: np.ndarray, path: np.ndarray,
                      waypoints: np.ndarray) -> list[str]:
    """Return what is wrong with one instance (an empty list when it is sound).

    Checks: every path pixel is free; the path is one 8-connected component; the start disc holds the
    polyline's first point and the goal disc its last; the polyline stays inside the window.
    """
    problems = []
    size = occupancy.shape
    path = np.asarray(path, dtype=bool)
    if not path.any():
        return ["empty path channel"]
    if (np.asarray(occupancy)[path] != FREE_CODE).any():
        problems.append(f"{int((np.asarray(occupancy)[path] != FREE_CODE).sum())} path pixels off free space")
    _, n = ndimage.label(path, structure=EIGHT)
    if n != 1:
        problems.append(f"path channel has {n} 8-connected components")
    wp = np.asarray(waypoints, dtype=np.float64)
    if (wp < -0.5).any() or (wp[:, 0] > size[1] - 0.5).any() or (wp[:, 1] > size[0] - 0.5).any():
        problems.append("polyline leaves the window")
        return problems
    for name, disc, (x, y) in (("start", start, wp[0]), ("goal", goal, wp[-1])):
        if not np.asarray(disc, dtype=bool)[int(round(y)), int(round(x))]:
            problems.append(f"{name} disc does not hold the polyline's {'first' if name == 'start' else 'last'} point")
    return problems
