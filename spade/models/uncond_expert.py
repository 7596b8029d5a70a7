"""Unconditional diffusion expert (DBC): a U-Net of ConvNeXt blocks denoising the 4-channel instance stack.

The diffused image is (occupancy, start, goal, path) mapped to [-1, 1]. Each ConvNeXt block (Liu et al. 2022,
as used in diffusion U-Nets such as lucidrains' denoising-diffusion-pytorch) is: depthwise 7x7 conv, plus a
per-channel projection of the timestep embedding, GroupNorm(1) (a LayerNorm over C, H, W), pointwise MLP
(1x1 conv expanding ``mult`` times, GELU, 1x1 conv back), and a residual (1x1 conv where the width changes).
The encoder keeps a skip per level; the decoder concatenates it before its first block.

The ``paper`` preset grows from 128 to 2048 channels (128, 256, 512, 1024, 2048) and has about one billion
parameters, like the paper's expert; build it on the ``meta`` device to inspect it without allocating.
"""

from __future__ import annotations

from typing import Any, Sequence

import torch
from torch import nn

from spade.models.layers import check_input, check_timesteps, time_mlp

UNCOND_EXPERT_PRESETS: dict[str, dict[str, Any]] = {
    # 1,027,482,884 parameters (the paper: "about 1 billion", channels 128 -> 2048).
    "paper": {"widths": (128, 256, 512, 1024, 2048), "blocks_per_level": 7, "mult": 4, "time_dim": 512},
    # CPU-friendly models for smoke runs and tests.
    "small": {"widths": (32, 64, 128, 256), "blocks_per_level": 2, "mult": 2, "time_dim": 64},
    "tiny": {"widths": (8, 16), "blocks_per_level": 1, "mult": 2, "time_dim": 16},
    # scale=cpu candidate (757k parameters): four levels (each 7x7 depthwise block sees far at 64 px), one block
    # per level; a training step at batch 32, 64 px costs about a quarter of "small"'s on one CPU thread.
    "cpu_lite": {"widths": (16, 32, 64, 128), "blocks_per_level": 1, "mult": 2, "time_dim": 32},
}


class ConvNeXtBlock(nn.Module):
    """Depthwise 7x7 conv (+ time embedding) -> norm -> 1x1 expand -> GELU -> 1x1 project, with a residual."""

    def __init__(self, in_ch: int, out_ch: int, time_dim: int, mult: int) -> None:
        super().__init__()
        self.dwconv = nn.Conv2d(in_ch, in_ch, 7, padding=3, groups=in_ch)
        self.time_proj = nn.Sequential(nn.GELU(), nn.Linear(time_dim, in_ch))
        self.norm = nn.GroupNorm(1, in_ch)
        self.mlp = nn.Sequential(nn.Conv2d(in_ch, mult * out_ch, 1), nn.GELU(), nn.Conv2d(mult * out_ch, out_ch, 1))
        self.residual = nn.Conv2d(in_ch, out_ch, 1) if in_ch != out_ch else nn.Identity()

    def forward(self, x: torch.Tensor, t_emb: torch.Tensor) -> torch.Tensor:
        h = self.dwconv(x) + self.time_proj(t_emb)[:, :, None, None]
        return self.mlp(self.norm(h)) + self.residual(x)


class UncondExpertUNet(nn.Module):
    """Noise predictor ``eps_hat = f(x_t, t)`` over the whole instance stack (no conditioning input).

    Args:
        in_channels: channels of the diffused image (4: occupancy, start, goal, path).
        widths: channels per level, shallow to deep; ``len(widths) - 1`` 2x downsamplings.
        blocks_per_level: ConvNeXt blocks per level in the encoder, the middle and the decoder.
        mult: expansion of the pointwise MLP.
        time_dim: timestep embedding size.
    """

    def __init__(
        self,
        in_channels: int = 4,
        widths: Sequence[int] = UNCOND_EXPERT_PRESETS["small"]["widths"],
        blocks_per_level: int = 2,
        mult: int = 2,
        time_dim: int = 64,
    ) -> None:
        super().__init__()
        widths = tuple(int(w) for w in widths)
        if not widths or blocks_per_level < 1 or mult < 1:
            raise ValueError(f"need non-empty widths and blocks_per_level, mult >= 1 (got {widths}, {blocks_per_level}, {mult})")
        self.preset: str | None = None  # set by the build_* functions
        self.in_channels = in_channels
        self.out_channels = in_channels
        self.condition_channels = 0
        self.widths, self.blocks_per_level, self.mult, self.time_dim = widths, blocks_per_level, mult, time_dim
        self.resolution_multiple = 2 ** (len(widths) - 1)
        n, k = len(widths), blocks_per_level

        self.time_embed = time_mlp(time_dim, nn.GELU)
        self.stem = nn.Conv2d(in_channels, widths[0], 7, padding=3)
        self.enc = nn.ModuleList(nn.ModuleList(ConvNeXtBlock(w, w, time_dim, mult) for _ in range(k)) for w in widths)
        self.downsample = nn.ModuleList(nn.Conv2d(widths[l], widths[l + 1], 4, stride=2, padding=1) for l in range(n - 1))
        self.mid = nn.ModuleList(ConvNeXtBlock(widths[-1], widths[-1], time_dim, mult) for _ in range(k))
        self.dec = nn.ModuleList(
            nn.ModuleList(ConvNeXtBlock(2 * w if i == 0 else w, w, time_dim, mult) for i in range(k)) for w in widths
        )
        self.upsample = nn.ModuleList(nn.ConvTranspose2d(widths[l], widths[l - 1], 4, stride=2, padding=1) for l in range(1, n))
        self.head = nn.Sequential(nn.GroupNorm(1, widths[0]), nn.Conv2d(widths[0], in_channels, 1))

    @property
    def config(self) -> dict[str, Any]:
        """What a checkpoint must agree with: channels and the required resolution multiple."""
        return {
            "role": "uncond_expert",
            "preset": self.preset,
            "in_channels": self.in_channels,
            "out_channels": self.out_channels,
            "condition_channels": self.condition_channels,
            "widths": list(self.widths),
            "blocks_per_level": self.blocks_per_level,
            "mult": self.mult,
            "time_dim": self.time_dim,
            "resolution_multiple": self.resolution_multiple,
        }

    def forward(self, x_t: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        who = "UncondExpertUNet"
        check_input(x_t, self.in_channels, self.resolution_multiple, who, "x_t")
        t_emb = self.time_embed(check_timesteps(t, x_t.shape[0], who).to(x_t.device))
        h = self.stem(x_t)
        skips = []
        for l, blocks in enumerate(self.enc):
            for b in blocks:
                h = b(h, t_emb)
            skips.append(h)
            if l < len(self.downsample):
                h = self.downsample[l](h)
        for b in self.mid:
            h = b(h, t_emb)
        for l in reversed(range(len(self.dec))):
            h = torch.cat((h, skips[l]), dim=1)
            for b in self.dec[l]:
                h = b(h, t_emb)
            if l > 0:
                h = self.upsample[l - 1](h)
        return self.head(h)


def build_uncond_expert(preset: str, in_channels: int = 4) -> UncondExpertUNet:
    """Build an unconditional expert preset: ``"paper"`` (~1e9 params, use the meta device), ``"small"``,
    ``"cpu_lite"`` or ``"tiny"``."""
    if preset not in UNCOND_EXPERT_PRESETS:
        raise ValueError(f"unknown uncond_expert preset {preset!r}; valid presets: {sorted(UNCOND_EXPERT_PRESETS)}")
    model = UncondExpertUNet(in_channels, **UNCOND_EXPERT_PRESETS[preset])
    model.preset = preset
    return model
