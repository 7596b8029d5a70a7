"""The references a test logs beside every predictor: the BC ceiling and the decoder's floor.

A learned planner sits between the floor (the best single path against one demonstration, :mod:`spade.metrics.
preference`) and what its training can at best reach. For BC that is the *ceiling*: the plausible set's pixelwise
mean (:func:`spade.data.plausible.ceiling_map`, the image binary cross-entropy converges to) decoded by the planner.
Beside it, the demonstration's own training target decoded by the planner: how close the decoder gets from a
perfect image of the one demonstration.
"""

from __future__ import annotations

import torch

from spade.data.augment import widen_path
from spade.data.plausible import ceiling_map, plausible_images
from spade.metrics.preference import medoid_path, plausible_set

__all__ = ["POLYLINE_REFERENCES", "REFERENCES", "reference_maps", "reference_polylines"]


REFERENCES: tuple[str, ...] = ("ceiling", "demo_target", "oracle_sample", "oracle_medoid")
"""The reference readings a test logs beside every predictor (``test/<name>/planner/...``): ``ceiling``, the BC
ceiling (:func:`ceiling_map` decoded by the planner); ``demo_target``, the demonstration's own training target
decoded by the planner (the decoder's own floor: how close a perfect image of the one demonstration decodes); and
the oracle as a planner, from the plausible set itself: ``oracle_sample``, a genuine alternative (another draw of
the generator from the same state: what a perfect sampler gives when asked once), and ``oracle_medoid``, the
minimum-Bayes-risk reading of the set (:func:`~spade.metrics.preference.medoid_path`: what a perfect sampler gives
with the medoid of its samples). The oracle's two are paths, scored as the baselines are (no decoding)."""
POLYLINE_REFERENCES: tuple[str, ...] = ("oracle_sample", "oracle_medoid")


@torch.no_grad()
def reference_maps(batch: dict, width_px: int) -> dict[str, torch.Tensor]:
    """The images of :data:`REFERENCES` for a test batch (the ceiling only where the batch has ``alternatives``)."""
    h, w = batch["path"].shape[-2:]
    out = {"demo_target": widen_path(batch["path"].float(), width_px)}
    if batch.get("alternatives") is not None:
        images, mask = plausible_images(batch["waypoints"], batch["alternatives"], h, w, width_px)
        out["ceiling"] = ceiling_map(images, mask)
    return out


def reference_polylines(batch: dict) -> dict[str, list]:
    """The oracle's paths of :data:`POLYLINE_REFERENCES` for a test batch with ``alternatives`` ({} without):
    window-pixel polylines, None where an instance has no alternative."""
    alternatives = batch.get("alternatives")
    if alternatives is None:
        return {}
    truth = batch["waypoints"].detach().cpu().double().numpy()
    alts = alternatives.detach().cpu().double().numpy()
    sample, medoid = [], []
    for i in range(truth.shape[0]):
        paths = plausible_set(truth[i], alts[i])
        if len(paths) < 2:
            sample.append(None)
            medoid.append(None)
            continue
        sample.append(paths[1])  # the first stored alternative: a draw of the generator, not the demonstration
        medoid.append(medoid_path(list(paths), points=paths.shape[1]))
    return {"oracle_sample": sample, "oracle_medoid": medoid}
