"""A fixed, versioned set of known corruptions of a demonstrated path: the test bench of an expert used as a critic.

A diffusion expert teaches a student through the margin only where it scores the demonstration better than what the
student predicts. Before a guided result is read, the expert (with the margin's formulation) must rank the
demonstration above paths known to be worse (docs/method.md, "Is the expert a critic?"; :mod:`spade.training.critic` scores them). Each
corruption turns a batch's path target (B, 1, H, W) in [0, 1], drawn at ``target_width_px`` like the training
target, into a worse candidate:

- ``blur``: the target blurred by a Gaussian of 1.5 px and rescaled to its peak of 1 (the same path, spread
  out: a soft, mode-averaged image, what a squared-error denoiser tends to prefer);
- ``faint``: the target at half intensity (a student half sure of the right path);
- ``shift1`` / ``shift3``: the target translated by 1 / 3 px in a direction drawn per instance (zeros move in);
- ``mirror``: the target mirrored about the robot's column (the wrong turn);
- ``straight``: the straight line from the path's start to its goal;
- ``empty``: no path at all;
- ``gap``: :data:`GAP_PX` of the path's arc length (at most half of it) cut out, centred where it turns most
  (mid-turn): a break twice the target's width, which a robot cannot drive across;
- ``radius``: the turn made wider (the path smoothed over :data:`RADIUS_WINDOW_PX` of arc length, ends kept):
  the same start, goal and shape with a turn wider than any demonstrated. A milder widening is not a corruption:
  the L presets draw a sharp (0.25-0.5 m) or a wide (0.7-1.0 m) radius per scenario, and nothing in the state
  says which, so a sharp turn widened to about 0.8 m is another scenario's valid demonstration.

The set and its parameters are versioned (:data:`CORRUPTION_SET_VERSION`): a critic figure names the version it
was measured on, and changing any corruption bumps it.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch
import torch.nn.functional as F

from spade.data.augment import mirror_images, widen_path
from spade.data.polyline import polyline_length, resample_polyline
from spade.metrics.baselines import draw_polylines
from spade.metrics.shape_paths import cut_gap

__all__ = ["CORRUPTIONS", "CORRUPTION_SET_VERSION", "corrupt", "turn_point", "wider_turn"]

CORRUPTION_SET_VERSION = 1
BLUR_SIGMA_PX = 1.5
GAP_PX = 6.0
RADIUS_WINDOW_PX = 32.0

#: The corruptions, in the order reports list them.
CORRUPTIONS: tuple[str, ...] = ("blur", "faint", "shift1", "shift3", "mirror", "straight", "empty", "gap", "radius")


def gaussian_blur(images: torch.Tensor, sigma: float) -> torch.Tensor:
    """Images (B, 1, H, W) blurred by a separable Gaussian of ``sigma`` px (zero padding, kernel of 3 sigma)."""
    radius = max(1, int(np.ceil(3 * sigma)))
    x = torch.arange(-radius, radius + 1, dtype=images.dtype, device=images.device)
    k = torch.exp(-0.5 * (x / sigma) ** 2)
    k = k / k.sum()
    out = F.conv2d(images, k.view(1, 1, 1, -1), padding=(0, radius))
    return F.conv2d(out, k.view(1, 1, -1, 1), padding=(radius, 0))


def shift_images(images: torch.Tensor, shifts: torch.Tensor) -> torch.Tensor:
    """Each image (B, 1, H, W) translated by its integer (dx, dy) in ``shifts`` (B, 2), zeros moving in."""
    out = torch.zeros_like(images)
    h, w = images.shape[-2:]
    for i, (dx, dy) in enumerate(shifts.tolist()):
        dx, dy = int(dx), int(dy)
        src = images[i, :, max(0, -dy):h - max(0, dy), max(0, -dx):w - max(0, dx)]
        out[i, :, max(0, dy):max(0, dy) + src.shape[-2], max(0, dx):max(0, dx) + src.shape[-1]] = src
    return out


def shift_directions(n: int, distance_px: int, seed: int) -> torch.Tensor:
    """``n`` integer shifts (dx, dy) of ``distance_px`` (Chebyshev length) in directions drawn by ``seed``: one of
    the eight compass directions per instance."""
    compass = np.array([(1, 0), (1, 1), (0, 1), (-1, 1), (-1, 0), (-1, -1), (0, -1), (1, -1)])
    pick = np.random.default_rng(seed).integers(0, len(compass), size=n)
    return torch.from_numpy(compass[pick] * int(distance_px))


def _dense(points: np.ndarray) -> np.ndarray:
    pts = np.asarray(points, np.float64)
    return resample_polyline(pts, max(8, int(np.ceil(polyline_length(pts) * 2)) + 1))


def turn_point(points: np.ndarray, window_px: float = 4.0) -> float:
    """Where a polyline turns most, as a fraction of its arc length (0.5 when it barely turns, under 20 degrees):
    the heading change over ``window_px`` of arc length either side of each point of a 0.5 px resampling."""
    dense = _dense(points)
    k, w = len(dense), max(1, int(round(window_px * 2)))
    if k < 2 * w + 1:
        return 0.5
    d = np.diff(dense, axis=0)
    heading = np.unwrap(np.arctan2(d[:, 1], d[:, 0]))
    change = np.abs(heading[2 * w - 1:] - heading[: len(heading) - 2 * w + 1])
    if np.degrees(change.max()) < 20.0:
        return 0.5
    plateau = np.flatnonzero(change >= change.max() - 1e-6)  # a sharp corner lies in 2w windows: take their middle
    return float((plateau.mean() + w) / (k - 1))


def wider_turn(points: np.ndarray, window_px: float = RADIUS_WINDOW_PX) -> np.ndarray:
    """The polyline smoothed by a moving average over ``window_px`` of arc length, its ends kept in place: the same
    start and goal with wider turns (a straight path is unchanged)."""
    dense = _dense(points)
    k, half = len(dense), max(1, int(round(window_px)))  # 0.5 px spacing: window_px / 0.5 / 2 points a side
    if k < 3:
        return dense
    padded = np.concatenate([2 * dense[:1] - dense[half:0:-1], dense, 2 * dense[-1:] - dense[-2:-half - 2:-1]])
    kernel = np.ones(2 * half + 1) / (2 * half + 1)
    out = np.stack([np.convolve(padded[:, j], kernel, mode="valid") for j in range(2)], axis=1)
    out[0], out[-1] = dense[0], dense[-1]
    return out


def _polylines(waypoints: torch.Tensor, edit: Callable[[np.ndarray], list[np.ndarray]], height: int, width: int,
               width_px: int) -> torch.Tensor:
    """Edited polylines (each edit may give several pieces) drawn like the dataset's path channel, then widened."""
    images = []
    for pts in waypoints.detach().cpu().double().numpy():
        pieces = edit(pts)
        image = draw_polylines(pieces, height, width).amax(0, keepdim=True) if pieces else \
            torch.zeros(1, 1, height, width)
        images.append(image.reshape(1, height, width))
    return widen_path(torch.stack(images), width_px).to(waypoints.device)


def corrupt(name: str, target: torch.Tensor, waypoints: torch.Tensor, robot_x: float, width_px: int,
            seed: int = 0) -> torch.Tensor:
    """Corruption ``name`` of a batch: ``target`` (B, 1, H, W) the demonstrations drawn at ``width_px`` (the
    training target), ``waypoints`` (B, K, 2) their polylines in pixels (x = column), ``robot_x`` the robot's
    column (the mirror axis). Returns candidates (B, 1, H, W) in [0, 1], on ``target``'s device and dtype."""
    h, w = target.shape[-2:]
    dtype = target.dtype
    if name == "blur":
        out = gaussian_blur(target, BLUR_SIGMA_PX)
        out = out / out.flatten(1).amax(1).clamp_min(1e-8).view(-1, 1, 1, 1)
    elif name == "faint":
        out = 0.5 * target
    elif name in ("shift1", "shift3"):
        out = shift_images(target, shift_directions(target.shape[0], int(name[-1]), seed))
    elif name == "mirror":
        out = mirror_images(target, robot_x)
    elif name == "empty":
        out = torch.zeros_like(target)
    elif name == "straight":
        out = _polylines(waypoints, lambda p: [np.stack([p[0], p[-1]])], h, w, width_px)
    elif name == "gap":
        out = _polylines(waypoints, lambda p: cut_gap(p, min(0.5, GAP_PX / max(polyline_length(p), 1e-6)),
                                                           turn_point(p)), h, w, width_px)
    elif name == "radius":
        out = _polylines(waypoints, lambda p: [wider_turn(p)], h, w, width_px)
    else:
        raise ValueError(f"unknown corruption {name!r}; the set (version {CORRUPTION_SET_VERSION}) is "
                         f"{list(CORRUPTIONS)}")
    return out.to(device=target.device, dtype=dtype).clamp(0, 1)
