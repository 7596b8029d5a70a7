"""Building blocks shared by the diffusion experts: timestep embedding and 2-D upsampling/downsampling."""

from __future__ import annotations

import math

import torch
from torch import nn


class SinusoidalTimeEmbedding(nn.Module):
    """Transformer-style sinusoidal embedding of integer diffusion timesteps (as in DDPM / Diffusion Policy).

    Maps ``t`` (B,) to (B, dim) = [sin(t * f_k), cos(t * f_k)], with frequencies ``f_k = 10000 ** (-k / (dim/2 - 1))``.
    """

    def __init__(self, dim: int) -> None:
        super().__init__()
        if dim < 4 or dim % 2:
            raise ValueError(f"time embedding dim must be an even number >= 4, got {dim}")
        self.dim = dim
        half = dim // 2
        freqs = torch.exp(torch.arange(half, dtype=torch.float32) * -(math.log(10000.0) / (half - 1)))
        # A non-persistent buffer (never in a checkpoint) so that the embedding's output follows the module's
        # device and dtype (``.to()``, ``.double()``, ``.half()``) like the layers after it.
        self.register_buffer("freqs", freqs, persistent=False)

    def forward(self, t: torch.Tensor) -> torch.Tensor:
        # Arguments up to T x f_0 = 1000 need float32 (half precision rounds them to 0.5); the result takes the
        # module's dtype.
        args = t.float()[:, None] * self.freqs.float()[None, :]
        return torch.cat((args.sin(), args.cos()), dim=-1).to(self.freqs.dtype)


def time_mlp(dim: int, activation: type[nn.Module] = nn.Mish) -> nn.Sequential:
    """Sinusoidal embedding followed by Diffusion Policy's MLP: Linear(dim, 4 dim) - act - Linear(4 dim, dim)."""
    return nn.Sequential(SinusoidalTimeEmbedding(dim), nn.Linear(dim, 4 * dim), activation(), nn.Linear(4 * dim, dim))


def check_timesteps(t: torch.Tensor, batch: int, who: str) -> torch.Tensor:
    """Accept ``t`` as a (B,) or scalar integer tensor (a scalar is broadcast to the batch); raise a clear error otherwise."""
    if not torch.is_tensor(t):
        t = torch.as_tensor(t)
    if t.dim() == 0:
        t = t.expand(batch)
    if t.dim() != 1 or t.shape[0] != batch:
        raise ValueError(f"{who}: timesteps must have shape ({batch},) (one per sample) or be a scalar, got {tuple(t.shape)}")
    if t.is_floating_point():
        raise ValueError(f"{who}: timesteps must be integer (torch.long) diffusion steps, got dtype {t.dtype}")
    return t


def check_input(x: torch.Tensor, channels: int, multiple: int, who: str, name: str = "input") -> None:
    """Raise a ValueError naming the problem and the fix when ``x`` is not (B, channels, H, W) with H, W % multiple == 0."""
    if x.dim() != 4:
        raise ValueError(f"{who}: {name} must be a 4-D (B, C, H, W) tensor, got shape {tuple(x.shape)}")
    if x.shape[1] != channels:
        raise ValueError(f"{who}: {name} has {x.shape[1]} channels, the model expects {channels}")
    h, w = x.shape[-2:]
    if h % multiple or w % multiple:
        raise ValueError(
            f"{who}: {name} size {h}x{w} is not divisible by {multiple} (2**depth); "
            f"pad or resize it to a multiple of {multiple}, e.g. 128x128"
        )
