"""Picture of predictions: state, ground truth and prediction as one colour overlay per instance."""

from __future__ import annotations

import numpy as np
import torch


def overlay(state: torch.Tensor, target: torch.Tensor, prob: torch.Tensor | None = None) -> np.ndarray:
    """An RGB uint8 (H, W, 3) picture of one instance.

    Occupancy as grey levels (unknown dark, free mid-grey, obstacle white), the ground-truth path in green,
    the prediction in magenta (its intensity the probability), the start disc blue and the goal disc red.
    """
    occ = state[0].float().cpu().numpy()
    grey = np.where(occ >= 0.75, 235.0, np.where(occ >= 0.25, 130.0, 35.0))
    rgb = np.repeat(grey[..., None], 3, axis=2)
    gt = target[0].float().cpu().numpy() > 0.5
    rgb[gt] = [40, 200, 60]
    if prob is not None:
        p = prob[0].float().cpu().numpy()[..., None].clip(0, 1)
        rgb = rgb * (1 - p) + np.array([230.0, 40, 220]) * p
    rgb[state[1].cpu().numpy() > 0.5] = [40, 90, 255]
    rgb[state[2].cpu().numpy() > 0.5] = [240, 40, 40]
    return rgb.clip(0, 255).astype(np.uint8)


def prediction_grid(state: torch.Tensor, target: torch.Tensor, prob: torch.Tensor | None, ncols: int = 4,
                    pad: int = 2) -> np.ndarray:
    """Tile per-instance overlays of a batch (B, ...) into one RGB image."""
    b, _, h, w = state.shape
    ncols = min(ncols, b)
    nrows = (b + ncols - 1) // ncols
    grid = np.full((nrows * (h + pad) + pad, ncols * (w + pad) + pad, 3), 255, dtype=np.uint8)
    for i in range(b):
        r, c = divmod(i, ncols)
        y, x = pad + r * (h + pad), pad + c * (w + pad)
        grid[y : y + h, x : x + w] = overlay(state[i], target[i], None if prob is None else prob[i])
    return grid
