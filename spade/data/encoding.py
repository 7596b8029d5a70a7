"""How the start and the goal are drawn in a student's input: the marker encodings.

The paper's input draws the start and the goal as binary discs at their rounded pixels; a student then cannot see
where inside that pixel the goal lies, and a path ended at the disc's centre is up to half a pixel off the
demonstration's end (on the quickstart's test set about 1.9 cm of APE that no model can learn away: the
*floor*, :mod:`spade.metrics.preference`). The sub-pixel encodings draw the same markers at their exact position:

- ``binary`` (the paper's, the default): a filled disc of radius ``r + 0.5`` px at the rounded centre
  (:func:`spade.data.rasterize.render`, pixel for pixel);
- ``aa_disc``: the same disc anti-aliased at the exact centre: each pixel holds the share of it the disc covers
  (16 x 16 samples per pixel), so the channel's weighted centroid is the exact position;
- ``gaussian``: a blob ``exp(-d^2 / (2 s^2))``, ``s = (r + 0.5) / 2``, at the exact centre (values under 1e-3 are
  0), smooth in the position.

A dataset stores the binary discs and the exact polyline; the dataset re-draws the markers from the polyline's
ends (the robot and the goal) for another encoding, so one dataset serves every encoding. A model file records
its encoding (``data.marker_encoding``) and the planner draws what the model was trained on. numpy only: the
deploy install (no torch) imports it.
"""

from __future__ import annotations

import numpy as np

MARKER_ENCODINGS: tuple[str, ...] = ("binary", "aa_disc", "gaussian")
"""The encodings of the start and goal channels; ``binary`` is the paper's."""

__all__ = ["MARKER_ENCODINGS", "check_encoding", "marker_channel", "marker_channels"]


def check_encoding(name: str) -> str:
    """``name`` if it is a known encoding, else a ValueError naming them."""
    if name not in MARKER_ENCODINGS:
        raise ValueError(f"unknown marker encoding {name!r}: use one of {list(MARKER_ENCODINGS)} "
                         "(data.encoding=binary is the paper's)")
    return name


def marker_channel(centre_xy: np.ndarray, size: int, radius_px: float, encoding: str = "binary") -> np.ndarray:
    """(size, size) float32 channel with one marker at window pixel ``centre_xy`` (x = column, y = row)."""
    check_encoding(encoding)
    x, y = float(centre_xy[0]), float(centre_xy[1])
    reach = max(float(radius_px), 0.5) + 0.5  # the binary disc's radius (rasterize.render)
    if encoding == "binary":
        from skimage.draw import disk

        out = np.zeros((size, size), dtype=np.float32)
        rr, cc = disk((round(y), round(x)), reach, shape=(size, size))
        out[rr, cc] = 1.0
        return out
    if encoding == "aa_disc":
        return _covered(x, y, reach, size)
    rows, cols = np.mgrid[0:size, 0:size]
    dist = np.hypot(cols - x, rows - y)
    sigma = reach / 2.0
    blob = np.exp(-(dist ** 2) / (2.0 * sigma ** 2))
    blob[blob < 1e-3] = 0.0
    return blob.astype(np.float32)


_SUB = 16  # samples per pixel side for the anti-aliased disc's coverage


def _covered(x: float, y: float, radius: float, size: int) -> np.ndarray:
    """The share of each pixel (a unit square about its centre) a disc of ``radius`` at (x, y) covers, from
    ``_SUB`` x ``_SUB`` samples per pixel (a box filter: the channel's weighted centroid is the disc's centre)."""
    out = np.zeros((size, size), dtype=np.float32)
    c0, c1 = max(int(np.floor(x - radius - 1)), 0), min(int(np.ceil(x + radius + 1)), size - 1)
    r0, r1 = max(int(np.floor(y - radius - 1)), 0), min(int(np.ceil(y + radius + 1)), size - 1)
    if c0 > c1 or r0 > r1:
        return out
    offsets = (np.arange(_SUB) + 0.5) / _SUB - 0.5
    cols = np.arange(c0, c1 + 1)[:, None] + offsets[None, :]  # (C, SUB)
    rows = np.arange(r0, r1 + 1)[:, None] + offsets[None, :]  # (R, SUB)
    inside = ((cols[None, :, None, :] - x) ** 2 + (rows[:, None, :, None] - y) ** 2) <= radius ** 2
    out[r0:r1 + 1, c0:c1 + 1] = inside.mean(axis=(2, 3))
    return out


def marker_channels(start_xy: np.ndarray, goal_xy: np.ndarray, size: int, radius_px: float,
                    encoding: str = "binary") -> np.ndarray:
    """(2, size, size) float32: the start and the goal channels of a student's input."""
    return np.stack([marker_channel(start_xy, size, radius_px, encoding),
                     marker_channel(goal_xy, size, radius_px, encoding)])
