"""APE: absolute pose error (cm) between the path extracted from a predicted image and the ground-truth polyline."""

from __future__ import annotations

import numpy as np
import torch
from torchmetrics import Metric
from torchmetrics.utilities import dim_zero_cat

from spade.metrics._inputs import cat_state, check_images, check_same_batch, per_instance_resolution, to_numpy
from spade.metrics.decoding import PathDecoder
from spade.metrics.extraction import extract_path, marker_centre
from spade.metrics.geometry import polyline_ape
from spade.data.polyline import resample_polyline

DECODERS = ("skeleton", "search")
"""How a predicted image becomes a polyline: the paper's extraction, or the planner's search decoder."""

__all__ = ["APE"]


class APE(Metric):
    """Absolute pose error in centimetres, translation part, no alignment (what evo's APE reports, averaged).

    Per instance: :func:`~spade.metrics.extraction.extract_path` turns the predicted probability image into an
    ordered polyline with as many points as the ground truth, both resampled evenly by arc length; the APE is
    the mean Euclidean distance between corresponding points times metres per pixel times 100. An instance from
    which no path can be extracted is a failure: it is counted (``failures``, ``failure_rate``) and has no APE.

    ``decoder``: ``skeleton`` (default, the paper's extraction, :func:`~spade.metrics.extraction.extract_path`) or
    ``search`` (the planner's path, :class:`~spade.metrics.decoding.PathDecoder`: the minimum-cost path over
    ``-log p`` on the window's costmap from the robot to the goal; it fails only when no free path exists).
    :meth:`update_polylines` scores polylines obtained elsewhere (a baseline's, or decoded once and shared).

    ``compute()`` returns tensors: ``ape_cm`` (mean over extracted instances), ``ape_std_cm`` (population std),
    ``ape_median_cm``, ``ape_max_cm`` (NaN when nothing was extracted), ``failures``, ``failure_rate``,
    ``instances``, ``over_<tail_cm>cm_rate`` (the tail: the share of *all* instances whose APE exceeds
    ``tail_cm``, a failure counting as over it) and ``score_cm``: the mean over *every* instance of its APE, a failed extraction scoring the
    straight line's APE on that instance (the start-goal segment against the ground truth). ``ape_cm`` alone
    rewards a model that fails more (it averages only what it could extract); ``score_cm`` cannot be improved by
    failing, which is why checkpoint selection and sweeps minimise it. ``per_instance()`` gives the raw values
    (extracted instances only).
    """

    is_differentiable = False
    higher_is_better = False
    full_state_update = False

    def __init__(
        self,
        threshold: float = 0.5,
        max_gap: float = 2.0,
        goal_tolerance: float = 4.0,
        snap_endpoints: bool = True,
        decoder: str = "skeleton",
        tail_cm: float = 20.0,
        **kwargs,
    ) -> None:
        super().__init__(**kwargs)
        if decoder not in DECODERS:
            raise ValueError(f"APE decoder must be one of {list(DECODERS)}, got {decoder!r}")
        if not tail_cm > 0:
            raise ValueError(f"tail_cm must be > 0 centimetres, got {tail_cm}")
        self.decoder = decoder
        self.tail_cm = float(tail_cm)
        self.tail_key = f"over_{self.tail_cm:g}cm_rate"
        self.extract_kwargs = dict(
            threshold=threshold, max_gap=max_gap, goal_tolerance=goal_tolerance, snap_endpoints=snap_endpoints
        )
        self._search = PathDecoder(threshold=threshold, force_endpoints=True) if decoder == "search" else None
        self.add_state("values", default=[], dist_reduce_fx="cat")
        self.add_state("scores", default=[], dist_reduce_fx="cat")
        self.add_state("failures", default=torch.tensor(0, dtype=torch.long), dist_reduce_fx="sum")
        self.add_state("total", default=torch.tensor(0, dtype=torch.long), dist_reduce_fx="sum")
        self.add_state("tail", default=torch.tensor(0, dtype=torch.long), dist_reduce_fx="sum")

    def update(
        self,
        pred_prob: torch.Tensor | None,
        state: torch.Tensor,
        waypoints: torch.Tensor,
        resolution: torch.Tensor | float,
        polylines: list[np.ndarray | None] | None = None,
    ) -> None:
        """pred_prob (B,1,H,W) in [0,1]; state (B,3,H,W) [occupancy, start, goal]; waypoints (B,K,2) (x, y)
        pixels; resolution (B,) or scalar, metres per pixel. ``polylines``: one predicted (N, 2) polyline (x, y
        pixels, N >= 2) or None (a failure) per instance, scored instead of decoding ``pred_prob`` (then None)."""
        if polylines is None:
            polylines = self.extract(pred_prob, state, waypoints, resolution)
        self._score(polylines, state, waypoints, resolution)

    def extract(self, pred_prob: torch.Tensor, state: torch.Tensor, waypoints: torch.Tensor,
                resolution: torch.Tensor | float) -> list[np.ndarray | None]:
        """The polyline this metric reads from each predicted image (None where it fails), as :meth:`update`
        scores it: the paper's extraction, or the planner's search with ``decoder="search"``."""
        check_images(pred_prob, "pred_prob", 1)
        self._check_truth(state, waypoints)
        check_same_batch(("pred_prob", pred_prob), ("state", state), ("waypoints", waypoints))
        prob = to_numpy(pred_prob)[:, 0]
        s = to_numpy(state)
        k = int(waypoints.shape[1])
        res = per_instance_resolution(resolution, prob.shape[0])
        polylines: list[np.ndarray | None] = []
        for i in range(prob.shape[0]):
            if self._search is not None:
                found = self._search.decode_state(prob[i], s[i], float(res[i]))
            else:
                found = extract_path(prob[i], s[i, 1], s[i, 2], k, **self.extract_kwargs)
            polylines.append(found.points if found.ok else None)
        return polylines

    @staticmethod
    def _check_truth(state: torch.Tensor, waypoints: torch.Tensor) -> None:
        check_images(state, "state", 3)
        if waypoints.ndim != 3 or waypoints.shape[-1] != 2 or waypoints.shape[1] < 2:
            raise ValueError(f"waypoints must be (B, K, 2) with K >= 2 (x=col, y=row), got {tuple(waypoints.shape)}")
        check_same_batch(("state", state), ("waypoints", waypoints))

    def update_polylines(
        self,
        polylines: list[np.ndarray | None],
        state: torch.Tensor,
        waypoints: torch.Tensor,
        resolution: torch.Tensor | float,
    ) -> None:
        """Score one predicted polyline per instance ((N, 2) x, y pixels, any N >= 2; None: a failure) against the
        ground truth; ``state``, ``waypoints``, ``resolution`` as in :meth:`update`."""
        self.update(None, state, waypoints, resolution, polylines=polylines)

    def _score(self, polylines: list[np.ndarray | None], state: torch.Tensor, waypoints: torch.Tensor,
               resolution: torch.Tensor | float) -> None:
        self._check_truth(state, waypoints)
        b = state.shape[0]
        if len(polylines) != b:
            raise ValueError(f"update_polylines got {len(polylines)} polylines for a batch of {b} states")
        res = per_instance_resolution(resolution, b)
        markers = to_numpy(state)[:, 1:3]
        truth = to_numpy(waypoints, np.float64)
        k = truth.shape[1]
        values, scores = [], []
        failed = 0
        for i in range(b):
            poly = polylines[i]
            if poly is None or len(poly) < 2:
                failed += 1
                line = np.stack([marker_centre(markers[i, 0], "start"), marker_centre(markers[i, 1], "goal")])
                scores.append(polyline_ape(line, truth[i]) * res[i] * 100.0)
                continue
            poly = np.asarray(poly, np.float64)
            if len(poly) != k:
                poly = resample_polyline(poly, k)
            values.append(polyline_ape(poly, truth[i]) * res[i] * 100.0)
            scores.append(values[-1])
        # Always append (possibly empty) so that every rank holds a float64 tensor for the DDP gather.
        self.values.append(torch.tensor(values, dtype=torch.float64, device=self.device))
        self.scores.append(torch.tensor(scores, dtype=torch.float64, device=self.device))
        self.failures += failed
        self.total += b
        self.tail += failed + sum(v > self.tail_cm for v in values)

    def per_instance(self) -> torch.Tensor:
        """APE (cm) of every extracted instance seen so far (on this process; after compute(), of all)."""
        return dim_zero_cat(self.values) if len(self.values) else torch.zeros(0, dtype=torch.float64)

    def compute(self) -> dict[str, torch.Tensor]:
        vals = self.per_instance().double()
        nan = torch.tensor(float("nan"), dtype=torch.float64)
        total = self.total.clone()
        out = {
            "ape_cm": vals.mean() if vals.numel() else nan,
            "ape_std_cm": vals.std(unbiased=False) if vals.numel() else nan,
            "ape_median_cm": vals.quantile(0.5) if vals.numel() else nan,
            "ape_max_cm": vals.max() if vals.numel() else nan,
            "failures": self.failures.clone(),
            "failure_rate": (self.failures.double() / total.double()) if total > 0 else nan,
            "instances": total,
            self.tail_key: (self.tail.double() / total.double()) if total > 0 else nan,
        }
        scores = cat_state(self.scores)
        out["score_cm"] = scores.mean() if scores.numel() else nan
        return out
