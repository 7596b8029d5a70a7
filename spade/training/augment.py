"""The 8 symmetries of the square (dihedral group D4), applied consistently to images and polylines."""

from __future__ import annotations

import torch

NUM_SYMMETRIES = 8


def transform_images(images: torch.Tensor, g: int) -> torch.Tensor:
    """Apply symmetry ``g`` (0..7) to images (..., H, W): a transpose when g >= 4, then g % 4 quarter turns."""
    if not 0 <= g < NUM_SYMMETRIES:
        raise ValueError(f"symmetry index must be in 0..7, got {g}")
    if g >= 4:
        images = images.transpose(-1, -2)
    return torch.rot90(images, k=g % 4, dims=(-2, -1))


def transform_points(points: torch.Tensor, g: int, size: int) -> torch.Tensor:
    """Apply symmetry ``g`` to pixel coordinates (..., 2) as (x = column, y = row) of a ``size`` x ``size`` image.

    Consistent with :func:`transform_images`: a point on a set pixel lands on the transformed set pixel.
    """
    x, y = points[..., 0], points[..., 1]
    if g >= 4:
        x, y = y, x
    last = size - 1
    for _ in range(g % 4):
        # torch.rot90(k=1, dims=(-2, -1)): new[r, c] = old[c, last - r]  =>  (x, y) -> (y, last - x)
        x, y = y, last - x
    return torch.stack([x, y], dim=-1)


def augment_batch(batch: dict, generator: torch.Generator | None = None) -> dict:
    """Draw one symmetry per instance and apply it to ``state``, ``path`` and ``waypoints`` of a square batch."""
    state, path, waypoints = batch["state"], batch["path"], batch["waypoints"]
    h, w = state.shape[-2:]
    if h != w:
        raise ValueError(f"D4 augmentation needs square instances, got {h} x {w}; set data.augment=false")
    g = torch.randint(0, NUM_SYMMETRIES, (state.shape[0],), generator=generator)
    new_state, new_path, new_wp = state.clone(), path.clone(), waypoints.clone()
    for k in range(NUM_SYMMETRIES):
        idx = (g == k).nonzero(as_tuple=True)[0]
        if k == 0 or len(idx) == 0:
            continue
        idx = idx.to(state.device)
        new_state[idx] = transform_images(state[idx], k)
        new_path[idx] = transform_images(path[idx], k)
        new_wp[idx] = transform_points(waypoints[idx], k, h)
    return {**batch, "state": new_state, "path": new_path, "waypoints": new_wp}
