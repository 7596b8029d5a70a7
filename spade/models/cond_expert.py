"""Conditional diffusion expert (Cond-DBC): a 2-D U-Net denoiser over the path channel, FiLM-conditioned on the state.

The design is Diffusion Policy's ``ConditionalUnet1D`` (real-stanford/diffusion_policy) carried to images:
every residual block is ``conv-GN-Mish -> FiLM -> conv-GN-Mish (+ 1x1 residual)``, and the FiLM scale and shift
come from the timestep embedding and the condition. Where Diffusion Policy pools the observation into one
global vector, a path image must know *where* the obstacles, start and goal are, so the condition here is a
feature map: a small conv encoder reads the 3-channel state resized to each U-Net resolution, and a 1x1 conv
turns its features into a per-pixel scale and shift at that resolution. The timestep embedding adds a
per-channel scale and shift (a sum of the two projections is a linear map of their concatenation, which is
what Diffusion Policy does). FiLM is applied as ``(1 + scale) * h + shift`` so that a freshly built block
starts near the identity.
"""

from __future__ import annotations

from typing import Any, Sequence

import torch
import torch.nn.functional as F
from torch import nn

from spade.models.layers import check_input, check_timesteps, time_mlp

COND_EXPERT_PRESETS: dict[str, dict[str, Any]] = {
    # 9,218,465 parameters: the size of the paper's conditional expert (9,218,561) to within 0.001 %.
    "paper": {"widths": (32, 80, 160, 192), "cond_widths": (32, 32, 64, 64), "time_dim": 128},
    # CPU-friendly models for smoke runs and tests.
    "small": {"widths": (16, 32, 64, 96), "cond_widths": (16, 16, 32, 32), "time_dim": 64},
    "tiny": {"widths": (8, 16), "cond_widths": (8, 8), "time_dim": 16},
    # Planners on a CPU: four levels at 64 px (8 px at the bottleneck: the receptive field covers the
    # window, where "tiny" sees about 20 px) and SiLU, which runs about 3x faster than Mish on a CPU (Mish and its
    # backward were 29 % of a training step). "cpu": scale=cpu; "cpu_lite": the quickstart's.
    "cpu": {"widths": (16, 32, 64, 96), "cond_widths": (16, 16, 32, 32), "time_dim": 64, "act": "silu"},
    "cpu_lite": {"widths": (8, 16, 32, 64), "cond_widths": (8, 8, 16, 32), "time_dim": 32, "act": "silu"},
}

ACTIVATIONS = {"mish": nn.Mish, "silu": nn.SiLU}


def _activation(act: str) -> nn.Module:
    if act not in ACTIVATIONS:
        raise ValueError(f"unknown activation {act!r}; valid: {sorted(ACTIVATIONS)}")
    return ACTIVATIONS[act]()


def _conv_gn_mish(in_ch: int, out_ch: int, groups: int, act: str = "mish") -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(in_ch, out_ch, 3, padding=1), nn.GroupNorm(_groups(out_ch, groups), out_ch),
                         _activation(act))


def _groups(channels: int, groups: int) -> int:
    """Largest group count <= ``groups`` that divides ``channels`` (so any width works with GroupNorm)."""
    g = min(groups, channels)
    while channels % g:
        g -= 1
    return g


class ConditionEncoder(nn.Module):
    """Encodes the state into one feature map per U-Net level (level l at H / 2**l).

    Level l sees the state resized to its resolution (area interpolation keeps every obstacle and the start/goal
    discs as fractional values) concatenated with the previous level's features downsampled by a stride-2 conv,
    so each level knows both the exact local layout and a wider context.
    """

    def __init__(self, condition_channels: int, widths: Sequence[int], groups: int, act: str = "mish") -> None:
        super().__init__()
        self.levels = nn.ModuleList()
        self.downs = nn.ModuleList()
        prev = 0
        for i, w in enumerate(widths):
            if i > 0:
                self.downs.append(nn.Conv2d(prev, prev, 3, stride=2, padding=1))
            self.levels.append(nn.Sequential(_conv_gn_mish(condition_channels + prev, w, groups, act),
                                             _conv_gn_mish(w, w, groups, act)))
            prev = w

    def forward(self, cond: torch.Tensor) -> list[torch.Tensor]:
        feats: list[torch.Tensor] = []
        h = None
        for i, level in enumerate(self.levels):
            size = (cond.shape[-2] >> i, cond.shape[-1] >> i)
            c = cond if i == 0 else F.interpolate(cond, size=size, mode="area")
            if h is not None:
                c = torch.cat((c, self.downs[i - 1](h)), dim=1)
            h = level(c)
            feats.append(h)
        return feats


class ConditionalResidualBlock2D(nn.Module):
    """``conv-GN-Mish -> FiLM(time, condition map) -> conv-GN-Mish``, plus a (1x1 conv) residual."""

    def __init__(self, in_ch: int, out_ch: int, time_dim: int, cond_ch: int, groups: int, act: str = "mish") -> None:
        super().__init__()
        self.block1 = _conv_gn_mish(in_ch, out_ch, groups, act)
        self.block2 = _conv_gn_mish(out_ch, out_ch, groups, act)
        self.time_film = nn.Sequential(_activation(act), nn.Linear(time_dim, 2 * out_ch))
        self.cond_film = nn.Sequential(_activation(act), nn.Conv2d(cond_ch, 2 * out_ch, 1))
        self.residual = nn.Conv2d(in_ch, out_ch, 1) if in_ch != out_ch else nn.Identity()

    def forward(self, x: torch.Tensor, t_emb: torch.Tensor, cond_map: torch.Tensor) -> torch.Tensor:
        h = self.block1(x)
        film = self.time_film(t_emb)[:, :, None, None] + self.cond_film(cond_map)
        scale, shift = film.chunk(2, dim=1)
        h = (1 + scale) * h + shift
        return self.block2(h) + self.residual(x)


class CondExpertUNet(nn.Module):
    """Noise predictor ``eps_hat = f(x_t, t, state)`` for the path channel.

    Args:
        in_channels: channels of the diffused image (1: the path).
        condition_channels: channels of the conditioning state (3: occupancy, start, goal).
        widths: U-Net channels per level, shallow to deep; ``len(widths) - 1`` 2x downsamplings.
        cond_widths: condition-encoder channels per level (same length as ``widths``).
        time_dim: timestep embedding size.
        groups: GroupNorm groups (reduced automatically to a divisor of each width).
        act: activation, ``"mish"`` (Diffusion Policy's) or ``"silu"`` (faster on a CPU).
    """

    def __init__(
        self,
        in_channels: int = 1,
        condition_channels: int = 3,
        widths: Sequence[int] = COND_EXPERT_PRESETS["paper"]["widths"],
        cond_widths: Sequence[int] = COND_EXPERT_PRESETS["paper"]["cond_widths"],
        time_dim: int = 128,
        groups: int = 8,
        act: str = "mish",
    ) -> None:
        super().__init__()
        _activation(act)
        widths, cond_widths = tuple(int(w) for w in widths), tuple(int(w) for w in cond_widths)
        if len(widths) < 1 or len(widths) != len(cond_widths):
            raise ValueError(f"widths {widths} and cond_widths {cond_widths} must be non-empty and of equal length")
        self.preset: str | None = None  # set by the build_* functions
        self.in_channels = in_channels
        self.out_channels = in_channels
        self.condition_channels = condition_channels
        self.widths, self.cond_widths, self.time_dim, self.groups, self.act = widths, cond_widths, time_dim, groups, act
        self.resolution_multiple = 2 ** (len(widths) - 1)

        self.time_embed = time_mlp(time_dim)
        self.cond_encoder = ConditionEncoder(condition_channels, cond_widths, groups, act)
        self.stem = nn.Conv2d(in_channels, widths[0], 3, padding=1)

        def block(i: int, o: int, level: int) -> ConditionalResidualBlock2D:
            return ConditionalResidualBlock2D(i, o, time_dim, cond_widths[level], groups, act)

        n = len(widths)
        self.enc = nn.ModuleList(nn.ModuleList([block(widths[l - 1] if l else widths[0], widths[l], l), block(widths[l], widths[l], l)]) for l in range(n))
        self.downsample = nn.ModuleList(nn.Conv2d(widths[l], widths[l], 3, stride=2, padding=1) for l in range(n - 1))
        self.mid = nn.ModuleList([block(widths[-1], widths[-1], n - 1), block(widths[-1], widths[-1], n - 1)])
        self.dec = nn.ModuleList(nn.ModuleList([block(2 * widths[l], widths[l], l), block(widths[l], widths[l], l)]) for l in range(n))
        self.upsample = nn.ModuleList(nn.ConvTranspose2d(widths[l], widths[l - 1], 4, stride=2, padding=1) for l in range(1, n))
        self.head = nn.Sequential(_conv_gn_mish(widths[0], widths[0], groups, act), nn.Conv2d(widths[0], in_channels, 1))

    @property
    def config(self) -> dict[str, Any]:
        """What a checkpoint must agree with: channels and the required resolution multiple."""
        return {
            "role": "cond_expert",
            "preset": self.preset,
            "in_channels": self.in_channels,
            "out_channels": self.out_channels,
            "condition_channels": self.condition_channels,
            "widths": list(self.widths),
            "cond_widths": list(self.cond_widths),
            "time_dim": self.time_dim,
            "groups": self.groups,
            "act": self.act,
            "resolution_multiple": self.resolution_multiple,
        }

    def forward(self, x_t: torch.Tensor, t: torch.Tensor, cond: torch.Tensor) -> torch.Tensor:
        who = "CondExpertUNet"
        check_input(x_t, self.in_channels, self.resolution_multiple, who, "x_t")
        check_input(cond, self.condition_channels, self.resolution_multiple, who, "cond")
        if cond.shape[0] != x_t.shape[0] or cond.shape[-2:] != x_t.shape[-2:]:
            raise ValueError(f"{who}: cond {tuple(cond.shape)} must match x_t {tuple(x_t.shape)} in batch size and H, W")
        t_emb = self.time_embed(check_timesteps(t, x_t.shape[0], who).to(x_t.device))
        cmaps = self.cond_encoder(cond.to(x_t.dtype))

        h = self.stem(x_t)
        skips = []
        for l, (b1, b2) in enumerate(self.enc):
            h = b2(b1(h, t_emb, cmaps[l]), t_emb, cmaps[l])
            skips.append(h)
            if l < len(self.downsample):
                h = self.downsample[l](h)
        for b in self.mid:
            h = b(h, t_emb, cmaps[-1])
        for l in reversed(range(len(self.dec))):
            b1, b2 = self.dec[l]
            h = b2(b1(torch.cat((h, skips[l]), dim=1), t_emb, cmaps[l]), t_emb, cmaps[l])
            if l > 0:
                h = self.upsample[l - 1](h)
        return self.head(h)


def build_cond_expert(preset: str = "paper", in_channels: int = 1, condition_channels: int = 3) -> CondExpertUNet:
    """Build a conditional expert preset: ``"paper"`` (~9.2M params), ``"small"``, ``"tiny"``, ``"cpu"`` or
    ``"cpu_lite"``."""
    if preset not in COND_EXPERT_PRESETS:
        raise ValueError(f"unknown cond_expert preset {preset!r}; valid presets: {sorted(COND_EXPERT_PRESETS)}")
    model = CondExpertUNet(in_channels, condition_channels, **COND_EXPERT_PRESETS[preset])
    model.preset = preset
    return model
