"""APE: absolute pose error (cm) between the path extracted from a predicted image and the ground-truth polyline."""

from __future__ import annotations

import numpy as np
import torch
from torchmetrics import Metric
from torchmetrics.utilities import dim_zero_cat

from spade.metrics._inputs import check_images, check_same_batch, to_numpy
from spade.metrics.extraction import extract_path, marker_centre
from spade.metrics.geometry import polyline_ape

__all__ = ["APE"]


class APE(Metric):
    """Absolute pose error in centimetres, translation part, no alignment (what evo's APE reports, averaged).

    Per instance: :func:`~spade.metrics.extraction.extract_path` turns the predicted probability image into an
    ordered polyline with as many points as the ground truth, both resampled evenly by arc length; the APE is
    the mean Euclidean distance between corresponding points times metres per pixel times 100. An instance from
    which no path can be extracted is a failure: it is counted (``failures``, ``failure_rate``) and has no APE.

    ``compute()`` returns tensors: ``ape_cm`` (mean over extracted instances), ``ape_std_cm`` (population std),
    ``ape_median_cm``, ``ape_max_cm`` (NaN when nothing was extracted), ``failures``, ``failure_rate``,
    ``instances``, and ``score_cm``: the mean over *every* instance of its APE, a failed extraction scoring the
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
        **kwargs,
    ) -> None:
        super().__init__(**kwargs)
        self.extract_kwargs = dict(
            threshold=threshold, max_gap=max_gap, goal_tolerance=goal_tolerance, snap_endpoints=snap_endpoints
        )
        self.add_state("values", default=[], dist_reduce_fx="cat")
        self.add_state("scores", default=[], dist_reduce_fx="cat")
        self.add_state("failures", default=torch.tensor(0, dtype=torch.long), dist_reduce_fx="sum")
        self.add_state("total", default=torch.tensor(0, dtype=torch.long), dist_reduce_fx="sum")

    def update(
        self,
        pred_prob: torch.Tensor,
        state: torch.Tensor,
        waypoints: torch.Tensor,
        resolution: torch.Tensor | float,
    ) -> None:
        """pred_prob (B,1,H,W) in [0,1]; state (B,3,H,W) [occupancy, start, goal]; waypoints (B,K,2) (x, y)
        pixels; resolution (B,) or scalar, metres per pixel."""
        check_images(pred_prob, "pred_prob", 1)
        check_images(state, "state", 3)
        if waypoints.ndim != 3 or waypoints.shape[-1] != 2 or waypoints.shape[1] < 2:
            raise ValueError(f"waypoints must be (B, K, 2) with K >= 2 (x=col, y=row), got {tuple(waypoints.shape)}")
        check_same_batch(("pred_prob", pred_prob), ("state", state), ("waypoints", waypoints))
        b = pred_prob.shape[0]
        res = to_numpy(resolution if isinstance(resolution, torch.Tensor) else np.asarray(resolution), np.float64).reshape(-1)
        if res.size == 1:
            res = np.full(b, float(res[0]))
        if res.size != b or not np.all(res > 0):
            raise ValueError(f"resolution must be a positive scalar or one value per instance (B={b}), got {res}")

        prob = to_numpy(pred_prob)[:, 0]
        markers = to_numpy(state)[:, 1:3]
        truth = to_numpy(waypoints, np.float64)
        k = truth.shape[1]
        values, scores = [], []
        failed = 0
        for i in range(b):
            result = extract_path(prob[i], markers[i, 0], markers[i, 1], k, **self.extract_kwargs)
            if not result.ok:
                failed += 1
                line = np.stack([marker_centre(markers[i, 0], "start"), marker_centre(markers[i, 1], "goal")])
                scores.append(polyline_ape(line, truth[i]) * res[i] * 100.0)
                continue
            values.append(polyline_ape(result.points, truth[i]) * res[i] * 100.0)
            scores.append(values[-1])
        # Always append (possibly empty) so that every rank holds a float64 tensor for the DDP gather.
        self.values.append(torch.tensor(values, dtype=torch.float64, device=self.device))
        self.scores.append(torch.tensor(scores, dtype=torch.float64, device=self.device))
        self.failures += failed
        self.total += b

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
        }
        scores = dim_zero_cat(self.scores).double() if len(self.scores) else torch.zeros(0, dtype=torch.float64)
        out["score_cm"] = scores.mean() if scores.numel() else nan
        return out
