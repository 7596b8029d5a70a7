"""The paper's three metrics over predicted path images, as one module the Lightning modules share.

On the metrics floor: it imports only :mod:`spade.metrics` modules (and torch / torchmetrics), never the training
package that uses it (``PathPlanningModule`` in :mod:`spade.training.base`)."""

from __future__ import annotations

import logging

import torch
from torchmetrics import Metric, MetricCollection
from torchmetrics.aggregation import MeanMetric

from spade.metrics._inputs import per_instance_resolution, to_numpy
from spade.metrics.ape import APE
from spade.metrics.baselines import draw_polylines
from spade.metrics.decoding import PathDecoder
from spade.metrics.fid import FID
from spade.metrics.hausdorff import HausdorffCount
from spade.metrics.preference import PREFERENCE_KEYS, PreferenceMetrics, instance_errors

log = logging.getLogger(__name__)
# (images, needed) pairs already warned of: a test scores the model and every baseline on the same instances, and
# each predictor's metrics said the same "FID left out" line again (one line per process and size)
_FID_WARNED: set[tuple[int, int]] = set()


PLANNER_KEYS: tuple[str, ...] = ("ape_cm", "ape_median_cm", "ape_max_cm", "failure_rate", "over_20cm_rate", "hd19",
                                  "low_confidence_rate", *PREFERENCE_KEYS)
"""The planner's figures a test logs (``planner/<key>``): MLflow's run page lists about 100 metrics, so the
planner's figures are the ones a reader compares, not every statistic (``planner_keys=None`` keeps them all)."""
INSTANCES_ARTIFACT = "test_instances.csv"
"""The run artifact a test writes its per-instance planner figures to (:attr:`PathMetrics.instance_rows` of every
predictor) and results pages read their intervals over scenarios from."""
BASELINE_PLANNER_KEYS: tuple[str, ...] = ("ape_cm", "failure_rate", "over_20cm_rate", *PREFERENCE_KEYS)


class PathMetrics(MetricCollection):
    """The paper's figures and the planner's, for predicted path probabilities against a batch's ground truth.

    A :class:`~torchmetrics.MetricCollection` of DDP-safe torchmetrics (``ape``, ``hd``, ``preference`` and, with the
    planner, ``planner_ape``, ``planner_hd``, ``low_confidence``, ``low_share``, ``planner_preference``; ``fid``):
    the collection moves, resets and syncs them; :meth:`update` extracts and decodes each batch once for all of
    them, and :meth:`compute` names their figures as a test logs them (each name in :mod:`spade.metrics.catalog`).

    - The paper's (keys ``ape_cm``, ``hd19``, ``failure_rate``, ``over_20cm_rate``, ...): the path extracted by
      threshold and skeleton (:func:`~spade.metrics.extraction.extract_path`), Hd19 of the thresholded image.
    - The planner's (keys ``planner/...``): the path :class:`~spade.metrics.decoding.PathDecoder` decodes by search
      from the robot to the goal (what ``Planner(decode="search")`` drives): its APE, tail and failures, Hd19 of
      that path drawn as a dataset's path channel, and ``planner/low_confidence_rate`` (the share of instances whose
      decoded path runs more than ``low_confidence_share`` of its length through pixels with p < 0.5).
    - FID compares like with like: the ground truth's path channel against every prediction's decoded path drawn
      exactly as that channel is drawn (one-pixel curve), so line width and probability texture cannot matter;
      a baseline's own polyline is drawn the same way.

    - Where the batch carries ``alternatives`` (a test set drawn with them), the figures that see a preference
      (:mod:`spade.metrics.preference`) for both readings: ``floor_cm`` (the predictor's own, the same for every
      predictor), ``ape_over_floor``, ``plausibility_cm``, ``commit_rate`` and ``planner/...``.

    :meth:`update` takes ``polylines`` for predictors that give a path rather than an image (the baselines): they
    are scored as the planner's path directly. FID needs more images than its feature dimension; on smaller sets
    (a tiny validation split) it is left out of the result with a warning rather than failing the run.
    """

    def __init__(self, hd_threshold: float = 19.0, pred_threshold: float = 0.5, fid_extractor: str | None = None,
                 fid_extractor_kwargs: dict | None = None, fid: bool = True, hd_threshold_m: float | None = 0.95,
                 planner: bool = True, tail_cm: float = 20.0, low_confidence_share: float = 0.1,
                 decoder: dict | None = None, planner_keys: tuple[str, ...] | None = PLANNER_KEYS,
                 commit_tol_cm: float = 1.5, record_instances: bool = False) -> None:
        if not 0 <= low_confidence_share <= 1:
            raise ValueError(f"low_confidence_share must lie in [0, 1], got {low_confidence_share}")
        # Hd19 in metres (0.95 m = 19 px of the paper's 0.05 m/px) so that coarser windows count the same
        # artifacts; the key stays "hd19". hd_threshold_m=null counts hd_threshold pixels instead.
        hd = dict(threshold=hd_threshold, pred_threshold=pred_threshold, threshold_m=hd_threshold_m,
                  name="hd19" if hd_threshold_m is not None else None)
        members: dict[str, Metric] = {"ape": APE(threshold=pred_threshold, tail_cm=tail_cm),
                                      "hd": HausdorffCount(**hd),
                                      "preference": PreferenceMetrics(commit_tol_cm=commit_tol_cm)}
        if planner:
            members.update(planner_ape=APE(threshold=pred_threshold, tail_cm=tail_cm),
                           planner_hd=HausdorffCount(**hd), low_confidence=MeanMetric(), low_share=MeanMetric(),
                           planner_preference=PreferenceMetrics(commit_tol_cm=commit_tol_cm))
        if fid:
            fid_args = () if fid_extractor is None else (fid_extractor,)
            members["fid"] = FID(*fid_args, extractor_kwargs=fid_extractor_kwargs)
        # compute_groups=False: two members with equal states after a batch (the paper's and the planner's APE on
        # one instance) must never be merged into one
        super().__init__(members, compute_groups=False)
        self.planner_keys = None if planner_keys is None else tuple(planner_keys)
        self.planner = planner
        self.low_confidence_share = float(low_confidence_share)
        self.decoder = PathDecoder(threshold=pred_threshold, force_endpoints=True, **dict(decoder or {}))
        if not fid:
            self.fid = None  # the member, when there is one
        self._warned = False
        # per-instance planner figures (scenario, APE, plausibility, commitment), for intervals over scenarios
        self.record_instances = bool(record_instances)
        self.instance_rows: list[dict] = []

    @property
    def fid_identity(self) -> str | None:
        return self.fid.identity if self.fid is not None else None

    def decode(self, prob: torch.Tensor, state: torch.Tensor, resolution: torch.Tensor | float
               ) -> list:
        """The planner's decoded path (:class:`~spade.metrics.decoding.DecodedPath`) of every instance."""
        p = to_numpy(prob)[:, 0]
        s = to_numpy(state)
        res = per_instance_resolution(resolution, len(p))
        return [self.decoder.decode_state(p[i], s[i], float(res[i])) for i in range(len(p))]

    @torch.no_grad()
    def update(self, prob: torch.Tensor, batch: dict, polylines: list | None = None) -> None:
        """``prob`` (B, 1, H, W) predicted path probabilities; ``polylines`` (optional, one (N, 2) array or None per
        instance): the predictor's own path, used as the planner's path instead of decoding ``prob``."""
        prob = prob.detach().float().clamp(0, 1)
        alternatives = batch.get("alternatives")
        paper = self.ape.extract(prob, batch["state"], batch["waypoints"], batch["resolution"])
        self.ape.update_polylines(paper, batch["state"], batch["waypoints"], batch["resolution"])
        if alternatives is not None:
            self.preference.update(paper, batch["state"], batch["waypoints"], alternatives, batch["resolution"])
        self.hd.update(prob, batch["path"], batch["resolution"])
        if not (self.planner or self.fid is not None):
            return
        if polylines is None:
            decoded = self.decode(prob, batch["state"], batch["resolution"])
            polylines = [d.points if d.ok else None for d in decoded]
            if self.planner:
                low = torch.tensor([float(d.low_confidence(self.low_confidence_share)) for d in decoded],
                                   dtype=torch.float32, device=prob.device)
                share = torch.tensor([d.low_share if d.ok else 1.0 for d in decoded], dtype=torch.float32,
                                     device=prob.device)
                self.low_confidence.update(low)
                self.low_share.update(share)
        h, w = prob.shape[-2:]
        drawn = draw_polylines(polylines, h, w, prob.device)
        if self.planner:
            self.planner_ape.update_polylines(polylines, batch["state"], batch["waypoints"], batch["resolution"])
            if alternatives is not None:
                self.planner_preference.update(polylines, batch["state"], batch["waypoints"], alternatives,
                                               batch["resolution"])
            self.planner_hd.update(drawn, batch["path"], batch["resolution"])
            if self.record_instances:
                self._record(polylines, batch)
        if self.fid is not None:
            self.fid.update(batch["path"].float(), real=True)
            self.fid.update(drawn, real=False)

    def _record(self, polylines: list, batch: dict) -> None:
        """One row per instance of the planner's figures (:func:`spade.metrics.preference.instance_errors`)."""
        truth = to_numpy(batch["waypoints"]).astype("float64")
        alternatives = batch.get("alternatives")
        alts = to_numpy(alternatives).astype("float64") if alternatives is not None else None
        res = per_instance_resolution(batch["resolution"], len(polylines))
        scenarios, maps = batch.get("scenario_id"), batch.get("map_id")
        tol = self.planner_preference.commit_tol_cm
        for i, poly in enumerate(polylines):
            ape, plaus = instance_errors(poly, truth[i], None if alts is None else alts[i], float(res[i]) * 100.0)
            self.instance_rows.append({
                "scenario": str(scenarios[i]) if scenarios is not None else "",
                "map": str(maps[i]) if maps is not None else "",
                "planner_ape_cm": ape, "planner_plausibility_cm": plaus,
                "planner_commit": (float(plaus <= tol) if plaus == plaus
                                   else 0.0 if self._has_alternatives(alts, i) else float("nan")),
                "planner_failed": float(ape != ape)})

    @staticmethod
    def _has_alternatives(alts, i: int) -> bool:
        import numpy as np

        return alts is not None and bool(np.isfinite(alts[i]).all(axis=(1, 2)).any())

    def reset(self) -> None:
        super().reset()
        self.instance_rows = []

    def compute(self) -> dict[str, float]:
        out = {k: float(v) for k, v in self.ape.compute().items()}
        out.update({k: float(v) for k, v in self.hd.compute().items()})
        if int(self.preference.counted) > 0:
            pref = self.preference.compute()
            out["floor_cm"] = float(pref["floor_cm"])
            out.update({k: float(pref[k]) for k in PREFERENCE_KEYS})
        if self.planner and self.planner_ape.total > 0:
            planner = {k: float(v) for k, v in self.planner_ape.compute().items() if k != "score_cm"}
            planner.update({k: float(v) for k, v in self.planner_hd.compute().items()
                            if k not in ("instances", "empty")})
            if self.low_confidence.update_count:
                planner["low_confidence_rate"] = float(self.low_confidence.compute())
                planner["low_share_mean"] = float(self.low_share.compute())
            if int(self.planner_preference.counted) > 0:
                pref = self.planner_preference.compute()
                planner.update({k: float(pref[k]) for k in PREFERENCE_KEYS})
            out.update({f"planner/{k}": v for k, v in planner.items()
                        if self.planner_keys is None or k in self.planner_keys})
        if self.fid is not None:
            have, need = int(self.fid.fake_n), self.fid.feature_dim + 1
            if have >= need:
                out.update({k: float(v) for k, v in self.fid.compute().items()})
            elif not self._warned and (have, need) not in _FID_WARNED:
                log.warning("FID left out: %d images, its extractor needs at least %d", have, need)
                self._warned = True
                _FID_WARNED.add((have, need))
        return out
