"""An instance's plausible set drawn as training targets: the BC ceiling's image and the oracle's candidates.

The *plausible set* of an instance is its demonstration and its stored alternatives (see
:func:`spade.metrics.preference.plausible_set`). Drawn as the training target is drawn (the dataset's one-pixel path
channel, widened to ``target_width_px``, :func:`spade.data.augment.widen_path`):

- :func:`ceiling_map`, the pixelwise mean of the set's images: binary cross-entropy against a target drawn at random
  from the set is minimised by it, so it is the image a perfect BC student converges to (decoded by the planner:
  the *BC ceiling*, :mod:`spade.metrics.plausible`), and the soft label of BC on the plausible set
  (``data.target_source=plausible_mean``);
- :func:`plausible_images`, the set itself: the candidates of the oracle denoiser (:mod:`spade.training.oracle`).
"""

from __future__ import annotations

import numpy as np
import torch

from spade.data.augment import widen_path
from spade.data.rasterize import draw_polyline

__all__ = ["ceiling_map", "plausible_images"]


def plausible_images(waypoints: torch.Tensor, alternatives: torch.Tensor | None, height: int, width: int,
                     width_px: int = 1) -> tuple[torch.Tensor, torch.Tensor]:
    """``(images, mask)``: each instance's demonstration then its alternatives drawn as training targets,
    ``images`` (B, 1 + A, 1, H, W) float32 in {0, 1}, ``mask`` (B, 1 + A) bool (False for an empty slot: a NaN row
    of ``alternatives``). ``waypoints`` (B, K, 2) and ``alternatives`` (B, A, K, 2) in window pixels; without
    alternatives the set is the demonstration alone."""
    truth = waypoints.detach().cpu().double().numpy()
    b = truth.shape[0]
    alts = (alternatives.detach().cpu().double().numpy() if alternatives is not None
            else np.zeros((b, 0) + truth.shape[1:]))
    if alts.shape[0] != b:
        raise ValueError(f"plausible_images got {b} demonstrations and {alts.shape[0]} rows of alternatives")
    n = 1 + alts.shape[1]
    images = np.zeros((b, n, 1, height, width), dtype=np.float32)
    mask = np.zeros((b, n), dtype=bool)
    for i in range(b):
        images[i, 0, 0] = draw_polyline(truth[i], height, width)
        mask[i, 0] = True
        for j in range(alts.shape[1]):
            if np.isfinite(alts[i, j]).all():
                images[i, 1 + j, 0] = draw_polyline(alts[i, j], height, width)
                mask[i, 1 + j] = True
    out = torch.from_numpy(images).to(waypoints.device)
    if width_px > 1:
        out = widen_path(out.flatten(0, 1), width_px).view(b, n, 1, height, width)
    return out, torch.from_numpy(mask).to(waypoints.device)


def ceiling_map(images: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """(B, 1, H, W): the pixelwise mean of each instance's plausible set (:func:`plausible_images`), the image that
    binary cross-entropy against a target drawn from the set is minimised by."""
    weights = mask.to(images.dtype)[:, :, None, None, None]
    return (images * weights).sum(1) / weights.sum(1).clamp_min(1.0)
