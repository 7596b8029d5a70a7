"""Turn a predicted path probability image into an ordered polyline from the start towards the goal.

Pipeline (one instance, CPU numpy): threshold -> skeleton (scikit-image) -> graph over skeleton pixels whose
edges join pixels at most ``max_gap + 1`` pixels apart (8-adjacency plus bridging of small gaps) -> keep the
connected component holding the skeleton pixel nearest the start -> Dijkstra (scipy.sparse.csgraph) from that
pixel -> end at the component pixel nearest the goal when it lies within ``goal_tolerance`` of the goal, else at
the geodesically farthest reachable pixel -> optional snapping of the two ends onto the start/goal centres ->
even resampling by arc length (:func:`spade.data.polyline.resample_polyline`).

Why these choices:
- A skeleton, not the raw mask, is ordered, so the polyline follows the centre line of a thick prediction.
- The start's component only: a stray blob is not part of the path the robot would drive (Hd19 flags it).
- Small gaps (default up to 2 pixels) between separate skeleton pieces are bridged: a one-pixel dropout in an otherwise correct prediction
  does not change where the robot would drive, and cutting the path there would make APE explode while the
  prediction is geometrically right. ``max_gap=0`` gives strict 8-connectivity.
- Ending at the farthest reachable pixel when the goal is not reached keeps a wrong-way prediction wrong
  (instead of collapsing it onto the pixel nearest the goal, which may be the start itself).
- Snapping: the skeleton of a thick line stops about half a line width short of its ends. Where the extracted
  end lies within the tolerance of the start/goal centre, that centre (a known fact: the robot stands there,
  the goal is given) is used as the end point, removing an extraction bias of the order of a pixel.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components, dijkstra
from scipy.spatial import cKDTree
from skimage.morphology import skeletonize

from spade.data.polyline import resample_polyline

__all__ = ["ExtractedPath", "extract_path", "marker_centre"]


@dataclass(frozen=True)
class ExtractedPath:
    """Result of :func:`extract_path`.

    ``points``: (num_points, 2) float64 polyline in pixel coordinates (x=col, y=row), evenly spaced by arc
    length, from the start towards the goal; ``None`` when extraction failed. ``pixels``: the ordered skeleton
    pixels (M, 2) (x, y) before snapping and resampling (empty on failure). ``failure``: ``None`` on success,
    else a short reason ("empty", "too_short"). ``reached_goal``: whether the path ends within the tolerance
    of the goal.
    """

    points: np.ndarray | None
    pixels: np.ndarray
    failure: str | None
    reached_goal: bool = False

    @property
    def ok(self) -> bool:
        return self.failure is None


def marker_centre(marker: np.ndarray, name: str = "marker") -> np.ndarray:
    """Centroid (x, y) of a start/goal marker channel, weighted by its values: the disc's centre for the paper's
    binary disc (values 0 or 1), the exact position for a sub-pixel encoding (an anti-aliased disc, a Gaussian
    blob: :mod:`spade.data.encoding`). Raises ValueError when the channel is empty."""
    weights = np.clip(np.asarray(marker, dtype=np.float64), 0.0, None)
    total = weights.sum()
    if not total > 0 or weights.max() < 0.05:
        raise ValueError(
            f"the {name} channel is empty (no pixel above 0.05); every instance needs a {name} marker in its state "
            "channels [occupancy, start, goal]"
        )
    rows, cols = np.indices(weights.shape)
    return np.array([(weights * cols).sum() / total, (weights * rows).sum() / total], dtype=np.float64)


def _failure(reason: str) -> ExtractedPath:
    return ExtractedPath(points=None, pixels=np.zeros((0, 2)), failure=reason)


def extract_path(
    pred_prob: np.ndarray,
    start: np.ndarray,
    goal: np.ndarray,
    num_points: int,
    threshold: float = 0.5,
    max_gap: float = 2.0,
    goal_tolerance: float = 4.0,
    snap_endpoints: bool = True,
) -> ExtractedPath:
    """Extract an ordered polyline of ``num_points`` points from a predicted path probability image.

    Args:
        pred_prob: (H, W) path probabilities in [0, 1].
        start, goal: (H, W) start/goal disc channels (> 0.5 inside the disc), or (2,) centre points (x, y).
        num_points: number of points of the resampled output polyline (>= 2).
        threshold: a pixel belongs to the prediction when ``pred_prob >= threshold``.
        max_gap: gaps of up to this many pixels between skeleton pixels are bridged (0: strict 8-connectivity).
        goal_tolerance: pixel distance within which the path counts as reaching the goal (and, with
            ``snap_endpoints``, within which the start/goal centres are used as the end points).
        snap_endpoints: replace the two ends by the start/goal centres when they lie within ``goal_tolerance``.
    """
    if num_points < 2:
        raise ValueError(f"extract_path needs num_points >= 2, got {num_points}")
    prob = np.asarray(pred_prob)
    if prob.ndim != 2:
        raise ValueError(f"extract_path expects a 2-D (H, W) probability image, got shape {prob.shape}")
    start_xy = _as_point(start, "start")
    goal_xy = _as_point(goal, "goal")

    mask = prob >= threshold
    if not mask.any():
        return _failure("empty")
    # Lee's method: Zhang's (the default) erases whole runs of 2-pixel-wide diagonal staircases, which is
    # exactly how a thin predicted line at 45 degrees often looks.
    skeleton = skeletonize(mask, method="lee")
    rows, cols = np.nonzero(skeleton)
    pts = np.stack([cols, rows], axis=1).astype(np.float64)  # (x, y)
    n = len(pts)

    # Graph over skeleton pixels: 8-neighbours, plus bridges of up to ``max_gap`` missing pixels between
    # different 8-connected pieces only (bridges inside a piece would let the path cut its own corners).
    radius = max(np.sqrt(2.0), float(max_gap) + 1.0) + 1e-6
    pairs = cKDTree(pts).query_pairs(radius, output_type="ndarray")
    weights = np.linalg.norm(pts[pairs[:, 0]] - pts[pairs[:, 1]], axis=1)
    if radius > 1.5:
        pieces, _ = ndimage.label(skeleton, structure=np.ones((3, 3), dtype=bool))
        piece = pieces[rows, cols]
        keep = (weights < 1.5) | (piece[pairs[:, 0]] != piece[pairs[:, 1]])
        pairs, weights = pairs[keep], weights[keep]
    graph = coo_matrix((weights, (pairs[:, 0], pairs[:, 1])), shape=(n, n)).tocsr()

    source = int(np.argmin(np.linalg.norm(pts - start_xy, axis=1)))
    _, labels = connected_components(graph, directed=False)
    component = np.flatnonzero(labels == labels[source])
    if len(component) < 2:
        return _failure("too_short")

    dist, pred = dijkstra(graph, directed=False, indices=source, return_predecessors=True)
    goal_dist = np.linalg.norm(pts[component] - goal_xy, axis=1)
    nearest_goal = int(component[np.argmin(goal_dist)])
    reached = bool(goal_dist.min() <= goal_tolerance)
    target = nearest_goal if reached else int(component[np.argmax(dist[component])])
    if target == source:
        return _failure("too_short")

    order = [target]
    while order[-1] != source:
        order.append(int(pred[order[-1]]))
    chain = pts[np.asarray(order[::-1])]

    poly = chain
    if snap_endpoints:
        if np.linalg.norm(chain[0] - start_xy) <= goal_tolerance:
            poly = np.vstack([start_xy, poly])
        if reached:
            poly = np.vstack([poly, goal_xy])
    points = resample_polyline(poly, num_points)
    return ExtractedPath(points=points, pixels=chain, failure=None, reached_goal=reached)


def _as_point(marker: np.ndarray, name: str) -> np.ndarray:
    arr = np.asarray(marker, dtype=np.float64)
    if arr.shape == (2,):
        return arr
    if arr.ndim != 2:
        raise ValueError(f"{name} must be an (H, W) disc channel or an (x, y) point, got shape {arr.shape}")
    return marker_centre(arr, name)

