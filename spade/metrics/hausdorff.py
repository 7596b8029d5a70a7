"""Hd19: how many instances have a Hausdorff distance above a threshold between prediction and ground truth."""

from __future__ import annotations

import math

import numpy as np
import torch
from torchmetrics import Metric
from torchmetrics.utilities import dim_zero_cat

from spade.metrics._inputs import cat_state, check_images, check_same_batch, to_numpy
from spade.metrics.geometry import mask_hausdorff

__all__ = ["HausdorffCount", "Hd19"]


def _threshold_name(threshold: float) -> str:
    return f"hd{int(threshold)}" if float(threshold).is_integer() else f"hd{threshold:g}"


class HausdorffCount(Metric):
    """Count of instances whose symmetric Hausdorff distance (pixels) exceeds ``threshold`` (default 19: "Hd19").

    The prediction is the full thresholded mask (``pred_prob >= pred_threshold``), not its skeleton, so that
    stray blobs and disconnected segments count; the ground truth is the target path channel (> 0.5). An empty
    prediction has distance ``inf`` and counts. The name follows the threshold (``self.name``: "hd19", "hd10").

    ``compute()`` returns tensors keyed by ``self.name``: ``<name>`` (count above the threshold),
    ``<name>_rate``, ``hausdorff_mean_px`` and ``hausdorff_median_px`` (finite distances only), ``empty``
    (empty predictions) and ``instances``.
    """

    is_differentiable = False
    higher_is_better = False
    full_state_update = False

    def __init__(self, threshold: float = 19.0, pred_threshold: float = 0.5, threshold_m: float | None = None,
                 name: str | None = None, **kwargs) -> None:
        super().__init__(**kwargs)
        if threshold < 0:
            raise ValueError(f"threshold must be >= 0 pixels, got {threshold}")
        if threshold_m is not None and not threshold_m > 0:
            raise ValueError(f"threshold_m must be > 0 metres (or null for a pixel threshold), got {threshold_m}")
        self.threshold = float(threshold)
        self.threshold_m = None if threshold_m is None else float(threshold_m)
        self.pred_threshold = float(pred_threshold)
        self.name = name or _threshold_name(threshold)
        self.add_state("distances", default=[], dist_reduce_fx="cat")
        self.add_state("limits", default=[], dist_reduce_fx="cat")

    def update(self, pred_prob: torch.Tensor, target_path: torch.Tensor,
               resolution: torch.Tensor | float | None = None) -> None:
        """pred_prob (B,1,H,W) in [0,1]; target_path (B,1,H,W) ground-truth path channel in {0,1}; ``resolution``
        (metres per pixel, scalar or per instance) is needed when the threshold is in metres (``threshold_m``):
        the paper's Hd19 is 19 px of a 128 px window at 0.05 m/px, i.e. 0.95 m, which is 9.5 px at 0.1 m/px."""
        check_images(pred_prob, "pred_prob", 1)
        check_images(target_path, "target_path", 1)
        check_same_batch(("pred_prob", pred_prob), ("target_path", target_path))
        if tuple(pred_prob.shape) != tuple(target_path.shape):
            raise ValueError(f"pred_prob {tuple(pred_prob.shape)} and target_path {tuple(target_path.shape)} differ")
        pred = to_numpy(pred_prob)[:, 0] >= self.pred_threshold
        truth = to_numpy(target_path)[:, 0] > 0.5
        empty_truth = ~truth.reshape(len(truth), -1).any(axis=1)
        if empty_truth.any():
            raise ValueError(
                f"target_path is empty for batch rows {np.flatnonzero(empty_truth).tolist()}; every instance needs a "
                "ground-truth path (check the dataset)"
            )
        dists = [mask_hausdorff(p, t) for p, t in zip(pred, truth)]
        if self.threshold_m is None:
            limits = np.full(len(dists), self.threshold)
        else:
            if resolution is None:
                raise ValueError(f"{self.name}: a threshold in metres ({self.threshold_m} m) needs the batch's resolution")
            res = to_numpy(resolution, np.float64).reshape(-1)
            limits = np.broadcast_to(self.threshold_m / res, (len(dists),)).astype(np.float64)
        self.distances.append(torch.tensor(dists, dtype=torch.float64, device=self.device))
        self.limits.append(torch.tensor(limits, dtype=torch.float64, device=self.device))

    def per_instance(self) -> torch.Tensor:
        """Hausdorff distance (pixels, inf for an empty prediction) of every instance seen so far."""
        return dim_zero_cat(self.distances) if len(self.distances) else torch.zeros(0, dtype=torch.float64)

    def compute(self) -> dict[str, torch.Tensor]:
        d = self.per_instance().double()
        limits = cat_state(self.limits)
        finite = d[torch.isfinite(d)]
        nan = torch.tensor(math.nan, dtype=torch.float64)
        count = (d > limits).sum()
        n = torch.tensor(d.numel(), device=d.device)
        return {
            self.name: count,
            f"{self.name}_rate": count.double() / n if d.numel() else nan,
            "hausdorff_mean_px": finite.mean() if finite.numel() else nan,
            "hausdorff_median_px": finite.quantile(0.5) if finite.numel() else nan,
            "empty": (~torch.isfinite(d)).sum(),
            "instances": n,
        }


Hd19 = HausdorffCount
