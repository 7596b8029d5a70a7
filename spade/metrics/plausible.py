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

__all__ = ["REFERENCES", "reference_maps"]


REFERENCES: tuple[str, ...] = ("ceiling", "demo_target")
"""The reference readings a test logs beside every predictor (``test/<name>/planner/...``): ``ceiling``, the BC
ceiling (:func:`ceiling_map` decoded by the planner), and ``demo_target``, the demonstration's own training target
decoded by the planner (the decoder's own floor: how close a perfect image of the one demonstration decodes)."""


@torch.no_grad()
def reference_maps(batch: dict, width_px: int) -> dict[str, torch.Tensor]:
    """The images of :data:`REFERENCES` for a test batch (the ceiling only where the batch has ``alternatives``)."""
    h, w = batch["path"].shape[-2:]
    out = {"demo_target": widen_path(batch["path"].float(), width_px)}
    if batch.get("alternatives") is not None:
        images, mask = plausible_images(batch["waypoints"], batch["alternatives"], h, w, width_px)
        out["ceiling"] = ceiling_map(images, mask)
    return out
