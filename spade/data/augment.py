"""Augmentation that is valid in the robot frame, and the widened path target.

In the robot frame (spade.maps.frame) the robot sits at a fixed pixel with its heading up the image, so a
rotation or a transpose would turn "forward" into "sideways": the only symmetry that keeps the frame is the
left-right mirror about the robot's column (a left turn becomes a right turn). The robot's column ``x_r`` is a
pixel centre, so the mirror maps column ``x`` to ``2 x_r - x``; columns that come from outside the window are
unknown (occupancy 0) and empty.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F


def check_augmentation(name: str | bool | None) -> str:
    """Normalise ``data.augment`` (``none`` / ``mirror``; false/null mean none)."""
    if name in (None, False, "none", "None"):
        return "none"
    if name == "mirror":
        return "mirror"
    raise ValueError(
        f"data.augment={name!r}: robot-frame windows allow only 'mirror' (left-right about the robot) or 'none'; "
        "rotations would turn the robot's heading sideways"
    )


def mirror_images(images: torch.Tensor, robot_x: float) -> torch.Tensor:
    """Mirror images (..., H, W) about column ``robot_x``: new[..., x] = old[..., 2 robot_x - x], zeros outside."""
    width = images.shape[-1]
    axis = 2.0 * float(robot_x)
    if not float(axis).is_integer():
        raise ValueError(f"the robot's column {robot_x} must be a pixel centre (integer) to mirror about it")
    shift = int(axis) - (width - 1)  # flip maps x -> (W - 1) - x; then shift by (2 x_r - (W - 1))
    flipped = torch.flip(images, dims=[-1])
    if shift == 0:
        return flipped
    out = torch.zeros_like(flipped)
    if shift > 0:
        out[..., shift:] = flipped[..., : width - shift]
    else:
        out[..., : width + shift] = flipped[..., -shift:]
    return out


def mirror_points(points: torch.Tensor, robot_x: float) -> torch.Tensor:
    """Mirror pixel coordinates (..., 2) (x = column, y = row) about column ``robot_x``."""
    out = points.clone()
    out[..., 0] = 2.0 * float(robot_x) - points[..., 0]
    return out


def augment_batch(batch: dict, robot_x: float, generator: torch.Generator | None = None) -> dict:
    """Mirror a random half of the batch about the robot's column (state, path, target, waypoints and, where the
    batch has them, alternative demonstrations)."""
    state = batch["state"]
    flip = torch.rand(state.shape[0], generator=generator) < 0.5
    idx = flip.nonzero(as_tuple=True)[0].to(state.device)
    if len(idx) == 0:
        return batch
    out = dict(batch)
    for key in ("state", "path", "target"):
        if key in batch:
            value = batch[key].clone()
            value[idx] = mirror_images(batch[key][idx], robot_x)
            out[key] = value
    for key in ("waypoints", "alternatives"):  # alternatives: NaN rows stay NaN
        if key in batch:
            points = batch[key].clone()
            points[idx] = mirror_points(batch[key][idx], robot_x)
            out[key] = points
    return out


def widen_path(path: torch.Tensor, width_px: int) -> torch.Tensor:
    """The path channel (B, 1, H, W) dilated to ``width_px`` pixels (odd; 1 returns it unchanged).

    The training target of the student (and the expert); the metrics keep the one-pixel path and the polyline.
    """
    width_px = int(width_px)
    if width_px < 1 or width_px % 2 == 0:
        raise ValueError(f"data.target_width_px must be an odd number of pixels >= 1, got {width_px}")
    if width_px == 1:
        return path
    return F.max_pool2d(path, kernel_size=width_px, stride=1, padding=width_px // 2)
