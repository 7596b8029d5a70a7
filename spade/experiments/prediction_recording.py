"""``python -m spade.evaluate ... mcap=PATH``: a test set's predictions next to the ground truth and the classical
baselines, as a ROS 2 MCAP recording a robotics person opens in Foxglove (:func:`spade.ros.recording.write_test_bag`).

The model runs here (torch), on the test set's first ``instances`` instances in their order; the paths are made as the
test's metrics make them (:meth:`spade.training.base.PathPlanningModule.test_step`): the paper's extraction
(:func:`spade.metrics.extraction.extract_path` with the test APE's settings) on ``/prediction`` and its APE on
``/ape_cm``, the planner's search decoder (the test metrics' :class:`~spade.metrics.decoding.PathDecoder`) on
``/prediction/planner``, each baseline's polyline (:func:`spade.metrics.baselines.baseline_polylines`) on
``/baseline/<name>``. The recording side gets numpy arrays only.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch.utils.data import DataLoader, Subset

from spade.utils.errors import ConfigError
from spade.metrics.baselines import BASELINES, baseline_polylines
from spade.metrics.decoding import PathDecoder
from spade.metrics.extraction import extract_path, marker_centre
from spade.metrics.geometry import polyline_ape
from spade.ros.recording import write_test_bag

__all__ = ["check_recording_instances", "instance_arrays", "record_test_set"]

log = logging.getLogger(__name__)


def check_recording_instances(value: Any, key: str = "mcap_instances") -> int:
    """``mcap_instances=``: how many test instances the recording holds, a whole number >= 1."""
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ConfigError(f"{key}={value}: give the number of test instances to record, a whole number >= 1 "
                          "(one per second of bag time)")
    return int(value)


def _dataset(subset: Any) -> Any:
    """The :class:`~spade.data.path_dataset.PathDataset` under (nested) subsets."""
    while isinstance(subset, Subset):
        subset = subset.dataset
    return subset


@torch.no_grad()
def instance_arrays(model: Any, test_set: Any, instances: int, batch_size: int = 16) -> dict[str, Any]:
    """The first ``instances`` instances of ``test_set`` with ``model``'s predictions, as numpy: ``occupancy``
    (N, H, W) codes, ``ground_truth`` (N, K, 2) and ``goals`` (N, 2) window pixels, ``resolution`` (N,),
    ``predictions`` and ``planner`` (one (M, 2) polyline or None each), ``baselines`` (name -> polylines),
    ``ape_cm`` (N,) (NaN where nothing was extracted), ``robot_px``."""
    n = min(int(instances), len(test_set))
    frame = _dataset(test_set).frame
    metrics = getattr(model, "test_metrics", None)
    extract_kwargs = dict(getattr(getattr(metrics, "ape", None), "extract_kwargs", None) or {})
    decoder = getattr(metrics, "decoder", None) or PathDecoder(force_endpoints=True)
    was_training = model.training
    model.eval()
    device = next(model.parameters()).device
    out: dict[str, Any] = {"occupancy": [], "ground_truth": [], "goals": [], "resolution": [], "predictions": [],
                           "planner": [], "baselines": {name: [] for name in BASELINES}, "ape_cm": [],
                           "robot_px": tuple(float(v) for v in frame["robot_px"])}
    loader = DataLoader(Subset(test_set, range(n)), batch_size=max(1, int(batch_size)), shuffle=False, num_workers=0)
    try:
        for batch in loader:
            state = batch["state"].to(device)
            prob = model.predict_paths({**batch, "state": state}).detach().float().clamp(0, 1).cpu().numpy()[:, 0]
            s = batch["state"].numpy()
            truth = batch["waypoints"].numpy().astype(np.float64)
            res = np.broadcast_to(np.asarray(batch["resolution"], dtype=np.float64).reshape(-1), (len(s),))
            shapes = batch.get("shape")
            for i in range(len(s)):
                r = float(res[i])
                found = extract_path(prob[i], s[i, 1], s[i, 2], truth.shape[1], **extract_kwargs)
                out["predictions"].append(found.points if found.ok else None)
                out["ape_cm"].append(polyline_ape(found.points, truth[i]) * r * 100.0 if found.ok else float("nan"))
                decoded = decoder.decode_state(prob[i], s[i], r)
                out["planner"].append(decoded.points if decoded.ok else None)
                shape = str(shapes[i]) if shapes is not None else None
                for name, poly in baseline_polylines(s[i], r, shape).items():
                    out["baselines"][name].append(poly)
                out["occupancy"].append(np.rint(s[i, 0] * 2).astype(np.uint8))  # 0 unknown, 0.5 free, 1 obstacle
                out["ground_truth"].append(truth[i])
                out["goals"].append(marker_centre(s[i, 2], "goal"))
                out["resolution"].append(r)
    finally:
        model.train(was_training)
    for key in ("occupancy", "ground_truth", "goals", "resolution", "ape_cm"):
        out[key] = np.asarray(out[key])
    return out


def record_test_set(model: Any, datamodule: Any, path: str | Path, instances: int = 64) -> Path:
    """Write ``datamodule``'s test set (its first ``instances``) with ``model``'s paths to ``path``
    (:func:`spade.ros.recording.write_test_bag`); returns the path written."""
    if getattr(datamodule, "test_set", None) is None:
        datamodule.setup("test")
    arrays = instance_arrays(model, datamodule.test_set, instances,
                             batch_size=int(getattr(datamodule, "eval_batch_size", 16) or 16))
    written = write_test_bag(path, arrays["occupancy"], arrays["ground_truth"], arrays["goals"],
                             resolution=arrays["resolution"], robot_px=arrays["robot_px"],
                             predictions=arrays["predictions"], planner=arrays["planner"],
                             baselines=arrays["baselines"], ape_cm=arrays["ape_cm"])
    log.info("recording of %d test instances written to %s", len(arrays["occupancy"]), written)
    return written
