"""The paper's three metrics over predicted path images, as one module the Lightning modules share."""

from __future__ import annotations

import logging

import torch
from torch import nn

from spade.metrics import APE, FID, HausdorffCount

log = logging.getLogger(__name__)


class PathMetrics(nn.Module):
    """APE (cm), Hd<threshold> (count) and FID of predicted path probabilities against a batch's ground truth.

    FID needs more images than its feature dimension; on smaller sets (a tiny validation split) it is left out
    of the result with a warning rather than failing the run.
    """

    def __init__(self, hd_threshold: float = 19.0, pred_threshold: float = 0.5, fid_extractor: str = "randconv",
                 fid_extractor_kwargs: dict | None = None, fid: bool = True, hd_threshold_m: float | None = 0.95
                 ) -> None:
        super().__init__()
        self.ape = APE(threshold=pred_threshold)
        # Hd19 in metres (0.95 m = 19 px of the paper's 0.05 m/px) so that coarser windows count the same
        # artifacts; the key stays "hd19". hd_threshold_m=null counts hd_threshold pixels instead.
        self.hd = HausdorffCount(threshold=hd_threshold, pred_threshold=pred_threshold, threshold_m=hd_threshold_m,
                                 name="hd19" if hd_threshold_m is not None else None)
        self.fid = FID(fid_extractor, fid_extractor_kwargs) if fid else None
        self._warned = False

    @property
    def fid_identity(self) -> str | None:
        return self.fid.identity if self.fid is not None else None

    @torch.no_grad()
    def update(self, prob: torch.Tensor, batch: dict) -> None:
        prob = prob.detach().float().clamp(0, 1)
        self.ape.update(prob, batch["state"], batch["waypoints"], batch["resolution"])
        self.hd.update(prob, batch["path"], batch["resolution"])
        if self.fid is not None:
            self.fid.update(batch["path"].float(), real=True)
            self.fid.update(prob, real=False)

    def compute(self) -> dict[str, float]:
        out = {k: float(v) for k, v in self.ape.compute().items()}
        out.update({k: float(v) for k, v in self.hd.compute().items()})
        if self.fid is not None:
            have, need = int(self.fid.fake_n), self.fid.feature_dim + 1
            if have >= need:
                out.update({k: float(v) for k, v in self.fid.compute().items()})
            elif not self._warned:
                log.warning("FID left out: %d images, its extractor needs at least %d", have, need)
                self._warned = True
        return out

    def reset(self) -> None:
        self.ape.reset()
        self.hd.reset()
        if self.fid is not None:
            self.fid.reset()
