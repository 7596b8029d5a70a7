"""Decode a predicted path probability image by search: the planner's path from the robot to the goal.

The paper's extraction (:func:`spade.metrics.extraction.extract_path`: threshold, skeleton, longest chain from
the start) defines its APE, and it stays the paper's metric. But a student whose probability dips below the
threshold in the middle of a turn (sharp and wide turns of the demonstrations disagree there) loses the whole
rest of its path to it, although the probability image still shows the way. A robot needs a path that starts at
the robot, ends at the goal and never crosses a non-free cell; learned planners of this family get it by search
over the network's output (Neural A* runs A* over its cost map, TransPath focal search over its path
probabilities).

:func:`decode_path` does that:

1. cost of a cell = ``-log(clip(g * p, p_min, 1))``, ``g *`` a Gaussian blur of ``centre_sigma_px`` (the path's
   negative log-likelihood, if pixels were independent; the blur makes the centre of a band of equally confident
   pixels cheaper than its edges, so that a student's 3 px wide prediction is followed along its centre line,
   not its inner edge, which shortcut every turn by a pixel), plus ``inflation_weight`` x the Nav2-style
   inflation decay of the window's costmap (:func:`spade.maps.costmap.build_costmap`, the annotation tool's
   costmap, TurtleBot3 footprint);
   obstacle and unknown cells are impassable, the lethal band closer to an obstacle than the robot radius costs
   ``lethal_cost`` (a robot already inside that band, a window next to a wall, may drive out of it);
2. the minimum-cost 8-connected path from the robot's pixel to the goal's centre (scikit-image's
   ``MCP_Geometric``, Dijkstra with geometric step lengths);
3. sub-pixel smoothing with the annotation tool's own smoother (:func:`spade.data.polyline.smooth_path`:
   Douglas-Peucker, then a spline pinned at both ends), kept only where it stays on free cells (else the grid
   path is used), then even resampling by arc length.

**Replanning** (``prior``, the previous plan of the same robot and goal in this window's pixels, with
``prior_weight`` > 0): a robot replans every half metre, and where the probability map holds two turns about
equally likely (a sharp and a wide one, both demonstrated) each replan would pick one afresh, so the robot wavers
between them. The previous plan is a prior: each cell's ``-log p`` is scaled by ``1 - prior_weight x
exp(-d^2 / 2 prior_sigma_px^2)``, ``d`` its distance to the previous plan (``prior_weight`` in [0, 1): a bounded
discount, a cell on the previous plan costing at least ``1 - prior_weight`` of what it did). A scale rather than a
subtraction keeps the network's ordering inside the band (the path still follows the probability ridge, not the
previous line: a subtracted discount floored at 0 made the band near that line free, pinned replans to it and
lowered commitment in a probe).
So the turn it chose is kept while the network still finds it plausible, and changes where the network gives it a
``-log p`` more than ``1 / (1 - prior_weight)`` times another way's, a move the robot's state called for. A
previous plan that crosses a non-free cell of the window (the map changed under it: an obstacle on it) is abandoned
whole (``DecodedPath.prior == "blocked"``): the path is decoded as without one. Without a prior (``None``, or
``prior_weight`` 0) the cost is exactly the one above.

**Keeping the plan** (``keep_ratio``, hysteresis): the prior still re-decodes, and a re-decoded path drifts inside
the band or flips its turn where two turns cost about the same. With ``keep_ratio`` set, a replan whose previous plan
is still usable (``used`` above: inside the window, on free cells) returns that plan itself, joined from the robot,
unless the fresh path costs less than ``1 / (1 + keep_ratio)`` of it on the plain cost (no discount), as Nav2's
planners replan only for a clearly better path (``DecodedPath.prior == "kept"``). A plan the network now finds far
less likely, or that the map blocks, is still replaced.

Its confidence: the share of the path's length through pixels with ``p < 0.5`` and the minimum ``p`` along it.
A plan through a region the network did not predict is still a path (often the right one: a small dip), but the
integrator can see it and fall back (``Planner(..., fallback="shortest")``).

Failures are only what is really impossible: the start or the goal off the window or on an impassable cell
(unless ``force_endpoints``, used for evaluating dataset instances whose disc centre may touch a wall pixel), or
no free path between them.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import ndimage
from skimage.graph import MCP_Geometric

from spade.data.polyline import polyline_length, resample_polyline, smooth_path
from spade.maps.costmap import build_costmap
from spade.maps.occupancy import FREE as FREE_CODE  # window occupancy codes 0 unknown, 1 free, 2 occupied
from spade.metrics.extraction import marker_centre

__all__ = ["DecodedPath", "PRIOR_SIGMA_PX", "PathDecoder", "decode_path", "FREE_CODE", "path_confidence"]

PRIOR_SIGMA_PX = 2.0
"""Reach of the previous plan's discount (:meth:`PathDecoder.prior_discount`): a Gaussian of this many pixels
about it (20 cm at the students' 0.1 m/px: the follower's offset from its plan; a sharp and a wide turn of an L
lie farther apart through the turn)."""
PRIOR_END_PX = 1.5
"""A previous plan's non-free cells this near the robot or the goal do not block it (their own cells may be
marked non-free by the window's conservative rotation)."""

DEFAULT_ROBOT: dict[str, float] = {"radius_m": 0.105, "inflation_radius_m": 0.55, "cost_scaling_factor": 3.0}
"""The annotation tool's footprint and inflation (conf/annotate.yaml): TurtleBot3 Burger, Nav2's defaults."""


@dataclass(frozen=True)
class DecodedPath:
    """Result of :func:`decode_path`.

    ``points``: (num_points, 2) float64 (x=col, y=row) window pixels from the start to the goal, evenly spaced by
    arc length; None on failure. ``pixels``: the grid path (M, 2) before smoothing. ``failure``: None, or
    ``start_blocked`` / ``goal_blocked`` (endpoint outside the window or on an impassable cell), ``no_free_path``.
    ``low_share``: share of the path's length through pixels with ``p < threshold``; ``min_prob``: the lowest
    ``p`` along it; ``smoothed``: whether the smoothed curve was kept (False: the grid path was, because the
    smoothed one cut a non-free cell). ``prior``: what became of a previous plan given as a prior: None (none
    given, or ``prior_weight`` 0), ``used``, ``blocked`` (it crossed a non-free cell: abandoned), ``outside`` (none
    of it lies in the window), ``kept`` (the previous plan itself, joined from the robot: ``keep_ratio``).
    """

    points: np.ndarray | None
    pixels: np.ndarray
    failure: str | None
    low_share: float = float("nan")
    min_prob: float = float("nan")
    smoothed: bool = False
    prior: str | None = None

    @property
    def ok(self) -> bool:
        return self.failure is None

    def low_confidence(self, max_low_share: float = 0.1) -> bool:
        """Whether more than ``max_low_share`` of the path runs through pixels the network gave ``p < 0.5``."""
        return (not self.ok) or self.low_share > max_low_share


def _failed(reason: str, prior: str | None = None) -> DecodedPath:
    return DecodedPath(points=None, pixels=np.zeros((0, 2)), failure=reason, prior=prior)


def _cells_along(points: np.ndarray, shape: tuple[int, int], step_px: float = 0.25
                 ) -> tuple[np.ndarray, np.ndarray]:
    """(rows, cols) of the pixels under a polyline (x, y) sampled every ``step_px`` of its length."""
    pts = np.asarray(points, np.float64)
    dense = resample_polyline(pts, max(2, int(np.ceil(polyline_length(pts) / step_px)) + 1))
    h, w = shape
    cols = np.clip(np.rint(dense[:, 0]).astype(np.int64), 0, w - 1)
    rows = np.clip(np.rint(dense[:, 1]).astype(np.int64), 0, h - 1)
    return rows, cols


def path_confidence(prob: np.ndarray, points: np.ndarray, threshold: float = 0.5, step_px: float = 0.25
                    ) -> tuple[float, float]:
    """(share of the length through pixels with ``p < threshold``, minimum ``p``) along a polyline (x, y)."""
    p = prob[_cells_along(points, prob.shape, step_px)]
    return float(np.mean(p < threshold)), float(p.min())


def _line_cost(cost: np.ndarray, points: np.ndarray, step_px: float = 0.25) -> float:
    """The integral of a per-cell cost (H, W) along a polyline (x, y): the sum over its cells sampled every
    ``step_px``, times the step (``inf`` where it crosses an impassable cell)."""
    pts = np.asarray(points, np.float64)
    length = polyline_length(pts)
    values = cost[_cells_along(pts, cost.shape, step_px)]
    return float(values.sum() * length / max(len(values) - 1, 1))


def _cells_free(grid: np.ndarray, points: np.ndarray) -> bool:
    return bool(np.all(grid[_cells_along(points, grid.shape)] == FREE_CODE))


class PathDecoder:
    """:func:`decode_path` with its options fixed (what the metrics and the planner hold)."""

    def __init__(self, num_points: int = 64, p_min: float = 1e-4, inflation_weight: float = 0.3,
                 lethal_cost: float = 20.0, smoothing_px: float = 0.25, simplify_px: float = 0.0,
                 threshold: float = 0.5, robot: Mapping[str, Any] | None = None,
                 force_endpoints: bool = False, centre_sigma_px: float = 0.7, prior_weight: float = 0.0,
                 prior_sigma_px: float = PRIOR_SIGMA_PX, keep_ratio: float | None = None) -> None:
        if num_points < 2:
            raise ValueError(f"num_points must be >= 2, got {num_points}")
        if not 0 < p_min < 1:
            raise ValueError(f"p_min must lie in (0, 1), got {p_min}")
        if inflation_weight < 0 or lethal_cost < 0:
            raise ValueError(f"inflation_weight and lethal_cost must be >= 0, got {inflation_weight}, {lethal_cost}")
        self.num_points, self.p_min = int(num_points), float(p_min)
        self.inflation_weight, self.lethal_cost = float(inflation_weight), float(lethal_cost)
        self.smoothing_px, self.simplify_px, self.threshold = float(smoothing_px), float(simplify_px), float(threshold)
        self.robot = dict(robot or DEFAULT_ROBOT)
        self.force_endpoints = bool(force_endpoints)
        if centre_sigma_px < 0:
            raise ValueError(f"centre_sigma_px must be >= 0, got {centre_sigma_px}")
        self.centre_sigma_px = float(centre_sigma_px)
        if not (np.isfinite(prior_weight) and 0 <= prior_weight < 1):
            raise ValueError(f"prior_weight must lie in [0, 1) (the share of -log p taken off on the previous plan; "
                             f"0: no prior), got {prior_weight}")
        if not (np.isfinite(prior_sigma_px) and prior_sigma_px > 0):
            raise ValueError(f"prior_sigma_px must be > 0 pixels, got {prior_sigma_px}")
        self.prior_weight, self.prior_sigma_px = float(prior_weight), float(prior_sigma_px)
        if keep_ratio is not None and not (np.isfinite(keep_ratio) and keep_ratio >= 0):
            raise ValueError(f"keep_ratio must be >= 0 (how much cheaper a fresh path must be to replace the previous "
                             f"plan; None: never kept), got {keep_ratio}")
        self.keep_ratio = None if keep_ratio is None else float(keep_ratio)

    def prior_discount(self, prior: np.ndarray | None, grid: np.ndarray, start: np.ndarray, goal: np.ndarray
                       ) -> tuple[np.ndarray | None, str | None]:
        """The per-cell discount (H, W), the share of ``-log p`` taken off, toward a previous plan ``prior`` (K, 2)
        (x, y) window pixels, and
        what became of it (:attr:`DecodedPath.prior`): (None, None) without a prior or with ``prior_weight`` 0;
        (None, ``blocked``) when it crosses a non-free cell farther than :data:`PRIOR_END_PX` from ``start`` and
        ``goal`` (whose own cells the window's rotation may mark non-free); (None, ``outside``) when none of it
        lies in the window."""
        if prior is None or (self.prior_weight == 0 and self.keep_ratio is None):
            return None, None
        pts = np.asarray(prior, np.float64).reshape(-1, 2)
        if len(pts) == 0 or not np.isfinite(pts).all():
            return None, None
        h, w = grid.shape
        if len(pts) > 1 and polyline_length(pts) > 0:
            pts = resample_polyline(pts, max(2, int(np.ceil(polyline_length(pts) / 0.25)) + 1))
        cells = np.rint(pts).astype(np.int64)
        inside = (cells[:, 0] >= 0) & (cells[:, 0] < w) & (cells[:, 1] >= 0) & (cells[:, 1] < h)
        if not inside.any():
            return None, "outside"
        pts, cells = pts[inside], cells[inside]
        near_end = np.minimum(np.linalg.norm(pts - np.asarray(start, np.float64), axis=1),
                              np.linalg.norm(pts - np.asarray(goal, np.float64), axis=1)) <= PRIOR_END_PX
        if np.any((grid[cells[:, 1], cells[:, 0]] != FREE_CODE) & ~near_end):
            return None, "blocked"
        if self.prior_weight == 0:  # kept or replaced whole (keep_ratio), never discounted
            return None, "used"
        off = np.ones(grid.shape, bool)
        off[cells[:, 1], cells[:, 0]] = False
        distance = ndimage.distance_transform_edt(off)
        return self.prior_weight * np.exp(-0.5 * (distance / self.prior_sigma_px) ** 2), "used"

    def cost(self, prob: np.ndarray, grid: np.ndarray, resolution: float, discount: np.ndarray | None = None
             ) -> np.ndarray:
        """The per-cell search cost (H, W) (``inf`` on obstacle and unknown cells); ``discount`` (H, W): the share
        of ``-log p`` taken off (:meth:`prior_discount`), None for none."""
        return self._combined(*self._cost_terms(prob, grid, resolution), discount)

    @staticmethod
    def _combined(nll: np.ndarray, rest: np.ndarray, discount: np.ndarray | None) -> np.ndarray:
        """:meth:`cost` from its terms: ``nll x (1 - discount) + rest``."""
        return (nll if discount is None else nll * (1.0 - discount)) + rest

    def _cost_terms(self, prob: np.ndarray, grid: np.ndarray, resolution: float) -> tuple[np.ndarray, np.ndarray]:
        """(``-log p`` of the centred probabilities, the rest of the cost: inflation, lethal band, step, ``inf`` off
        the free cells): :meth:`cost` is ``nll x (1 - discount) + rest``."""
        costmap = build_costmap(grid, resolution, self.robot, cost_weight=1.0)
        free = grid == FREE_CODE
        inflation = np.where(np.isfinite(costmap.cost), costmap.cost - 1.0, 1.0)  # Nav2 decay in [0, 1]
        p = prob.astype(np.float64)
        if self.centre_sigma_px > 0:
            p = ndimage.gaussian_filter(p, self.centre_sigma_px, mode="nearest")
        nll = -np.log(np.clip(p, self.p_min, 1.0))
        rest = self.inflation_weight * inflation
        rest[free & ~np.isfinite(costmap.cost)] += self.lethal_cost
        # A small step cost keeps the search from wandering over p = 1 plateaus (-log 1 = 0).
        rest += 1e-3
        rest[~free] = np.inf
        return nll, rest

    def _kept(self, prior: np.ndarray, plain: np.ndarray, fresh: np.ndarray, start: np.ndarray, goal: np.ndarray,
              prob: np.ndarray) -> DecodedPath | None:
        """The previous plan joined from the robot, when the fresh path is not clearly cheaper on the plain cost
        (module docstring: keeping the plan); None when it is, or when the previous plan does not reach the goal."""
        pts = np.asarray(prior, np.float64).reshape(-1, 2)
        goal, start = np.asarray(goal, np.float64), np.asarray(start, np.float64)
        if len(pts) < 2 or np.linalg.norm(pts[-1] - goal) > PRIOR_END_PX:
            return None
        pts = pts[np.linalg.norm(pts - start, axis=1) > 0.5]
        candidate = np.vstack([start, pts[:-1], goal])
        kept, new = _line_cost(plain, candidate), _line_cost(plain, fresh)
        if not (np.isfinite(kept) and kept <= (1.0 + self.keep_ratio) * new):
            return None
        low, pmin = path_confidence(prob, candidate, self.threshold)
        return DecodedPath(points=resample_polyline(candidate, self.num_points), pixels=candidate, failure=None,
                           low_share=low, min_prob=pmin, smoothed=False, prior="kept")

    def decode_state(self, prob: np.ndarray, state: np.ndarray, resolution: float) -> DecodedPath:
        """Decode one instance from its network input (3, H, W): occupancy ``code * 0.5``, start and goal discs."""
        grid = np.rint(np.asarray(state[0], np.float64) * 2).astype(np.uint8)
        return self(prob, grid, marker_centre(state[1], "start"), marker_centre(state[2], "goal"), resolution)

    def __call__(self, prob: np.ndarray, grid: np.ndarray, start: np.ndarray, goal: np.ndarray,
                 resolution: float, prior: np.ndarray | None = None) -> DecodedPath:
        """Decode one (H, W) probability image on the window's (H, W) uint8 occupancy codes, from ``start`` to
        ``goal`` (x, y) window pixels; ``resolution`` in metres per pixel (for the robot's footprint); ``prior``:
        the previous plan (K, 2) in these window pixels, from the robot on (module docstring: replanning)."""
        prob = np.asarray(prob)
        grid = np.asarray(grid)
        if prob.ndim != 2 or prob.shape != grid.shape:
            raise ValueError(f"decode_path needs (H, W) probabilities and occupancy of one shape, got "
                             f"{prob.shape} and {grid.shape}")
        if grid.dtype != np.uint8:
            grid = np.ascontiguousarray(grid, dtype=np.uint8)
        h, w = grid.shape
        discount, prior_state = self.prior_discount(prior, grid, start, goal)
        nll, rest = self._cost_terms(prob, grid, resolution)
        cost = self._combined(nll, rest, discount)
        ends = []
        for xy, name in ((start, "start"), (goal, "goal")):
            xy = np.asarray(xy, np.float64)
            col, row = int(np.rint(xy[0])), int(np.rint(xy[1]))
            if not (0 <= row < h and 0 <= col < w):
                return _failed(f"{name}_blocked", prior_state)
            if not np.isfinite(cost[row, col]):
                if not self.force_endpoints:
                    return _failed(f"{name}_blocked", prior_state)
                cost[row, col] = rest[row, col] = self.lethal_cost - np.log(self.p_min)
                nll[row, col] = 0.0
            ends.append((row, col))
        a, b = ends
        if a == b:
            pts = np.stack([np.asarray(start, np.float64), np.asarray(goal, np.float64)])
            return DecodedPath(resample_polyline(pts, self.num_points), pts, None, *path_confidence(
                prob, pts, self.threshold), prior=prior_state)
        mcp = MCP_Geometric(cost, fully_connected=True)
        cum, _ = mcp.find_costs([a], [b], find_all_ends=False)
        if not np.isfinite(cum[b]):
            return _failed("no_free_path", prior_state)
        grid_path = np.asarray(mcp.traceback(b), dtype=np.float64)[:, ::-1]  # (x, y)
        # The exact start and goal (sub-pixel centres) as the ends, as the ground truth has them.
        poly = np.vstack([np.asarray(start, np.float64), grid_path[1:-1], np.asarray(goal, np.float64)])
        smoothed = False
        if len(poly) > 2 and (self.smoothing_px > 0 or self.simplify_px > 0):
            smooth = smooth_path(poly, smoothing_px=self.smoothing_px, step_px=0.5, simplify_px=self.simplify_px)
            passable = grid
            if self.force_endpoints:  # a forced endpoint's own cell does not count against the smoothing
                passable = grid.copy()
                passable[a], passable[b] = FREE_CODE, FREE_CODE
            if _cells_free(passable, smooth):
                poly, smoothed = smooth, True
        if self.keep_ratio is not None and prior_state == "used":
            kept = self._kept(prior, nll + rest, poly, start, goal, prob)
            if kept is not None:
                return kept
        points = resample_polyline(poly, self.num_points)
        low, pmin = path_confidence(prob, poly, self.threshold)
        return DecodedPath(points=points, pixels=grid_path, failure=None, low_share=low, min_prob=pmin,
                           smoothed=smoothed, prior=prior_state)


def decode_path(prob: np.ndarray, grid: np.ndarray, start: np.ndarray, goal: np.ndarray, resolution: float,
                num_points: int = 64, **options: Any) -> DecodedPath:
    """The minimum-cost path over ``-log(p)`` plus the costmap's inflation from ``start`` to ``goal``.

    See the module docstring; ``options`` are :class:`PathDecoder`'s.
    """
    return PathDecoder(num_points=num_points, **options)(prob, grid, start, goal, resolution)
