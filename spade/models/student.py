"""Student BC policy: the U-Net family of SKIPP, with widths resized to the SPADE paper's parameter counts.

Block structure follows SKIPP's ``bc/UNetSkip.py`` (github.com/charbel-a-hC/SKIPP) exactly:

* ``stem``: 3x3 conv (padding 1, bias) from the input channels to ``widths[0]``; its output is not a skip.
* down block ``i`` (``widths[i] -> widths[i+1]``): conv3x3-ReLU-BN, conv3x3-ReLU-BN, then a stride-2 4x4 conv
  (padding 1) that halves H and W. Its (downsampled) output is stored as a skip.
* up block ``j`` (``widths[-1-j] -> widths[-2-j]``): concatenate the running tensor with the skip of the same
  resolution (so the first conv sees ``2 * widths[-1-j]`` channels), conv3x3-ReLU-BN twice, then a stride-2 4x4
  transposed conv (padding 1) that doubles H and W.
* ``head``: 1x1 conv to ``out_channels`` giving logits (SKIPP applied a sigmoid here; SPADE keeps logits and
  puts the sigmoid in the loss, ``BCEWithLogits``).

SKIPP has no separate bottleneck: the deepest skip is the output of the last down block itself, so the first
up block concatenates that tensor with itself. We keep this (it is part of SKIPP's parameter budget, which the
paper's counts are based on). All convs carry a bias, as in SKIPP (PyTorch's default).

Widths. SKIPP's tuples (16-32-64, 32-64-128-256, 16..1024) have about twice the paper's parameter counts.
The presets keep SKIPP's depth per size and shrink the widths by about 1/sqrt(2) (which halves the count);
the tuples come from an exhaustive search over non-decreasing widths of that depth, keeping the most nearly
doubling tuple that hits the paper's count exactly (or, where none can, a doubling tuple within 1 %):

* ``small``  (12, 24, 44):                         118,165 params (+0.97 % of 117,025; no non-decreasing integer
  tuple of depth 2 gives 117,025 exactly);
* ``medium`` (24, 34, 90, 188):                  1,926,209 params (exactly the paper's figure);
* ``large``  (16, 28, 60, 108, 200, 408, 632): 31,114,785 params (exactly the paper's figure).
"""

from __future__ import annotations

from typing import Any, Sequence

import torch
from torch import nn

from spade.models.layers import check_input
from spade.models.paper_sizes import PAPER_PARAMETER_COUNTS  # noqa: F401  (re-exported)

STUDENT_PRESETS: dict[str, tuple[int, ...]] = {
    "small": (12, 24, 44),
    "medium": (24, 34, 90, 188),
    "large": (16, 28, 60, 108, 200, 408, 632),
}
"""Channel widths per level, shallow to deep; depth (number of 2x downsamplings) is ``len(widths) - 1``."""



class _ConvBlock(nn.Module):
    """SKIPP's ``ConvBlockBC``: two conv3x3-ReLU-BN layers, then a stride-2 resampling (conv or transposed conv)."""

    def __init__(self, in_ch: int, out_ch: int, up: bool) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(in_ch, out_ch, 3, padding=1)
        self.bn1 = nn.BatchNorm2d(out_ch)
        self.conv2 = nn.Conv2d(out_ch, out_ch, 3, padding=1)
        self.bn2 = nn.BatchNorm2d(out_ch)
        self.relu = nn.ReLU()
        resample = nn.ConvTranspose2d if up else nn.Conv2d
        self.transform = resample(out_ch, out_ch, 4, stride=2, padding=1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        h = self.bn1(self.relu(self.conv1(x)))
        h = self.bn2(self.relu(self.conv2(h)))
        return self.transform(h)


class StudentUNet(nn.Module):
    """SKIPP-style U-Net mapping the (B, in_channels, H, W) state to (B, out_channels, H, W) path logits.

    H and W must be divisible by ``2 ** depth`` with ``depth = len(widths) - 1``.
    """

    def __init__(self, in_channels: int = 3, out_channels: int = 1, widths: Sequence[int] = STUDENT_PRESETS["medium"]) -> None:
        super().__init__()
        widths = tuple(int(w) for w in widths)
        if len(widths) < 2:
            raise ValueError(f"widths needs at least 2 levels (got {widths}); e.g. widths=(16, 32, 64)")
        if any(w <= 0 for w in widths) or in_channels <= 0 or out_channels <= 0:
            raise ValueError(f"channel counts must be positive: in={in_channels}, out={out_channels}, widths={widths}")
        self.preset: str | None = None  # set by the build_* functions
        self.in_channels = in_channels
        self.out_channels = out_channels
        self.widths = widths
        self.depth = len(widths) - 1
        self.resolution_multiple = 2**self.depth

        self.stem = nn.Conv2d(in_channels, widths[0], 3, padding=1)
        self.downs = nn.ModuleList(_ConvBlock(widths[i], widths[i + 1], up=False) for i in range(self.depth))
        rev = widths[::-1]
        self.ups = nn.ModuleList(_ConvBlock(2 * rev[i], rev[i + 1], up=True) for i in range(self.depth))
        self.head = nn.Conv2d(widths[0], out_channels, 1)

    @property
    def config(self) -> dict[str, Any]:
        """What a checkpoint must agree with: channels, widths and the required resolution multiple."""
        return {
            "role": "student",
            "preset": self.preset,
            "in_channels": self.in_channels,
            "out_channels": self.out_channels,
            "widths": list(self.widths),
            "resolution_multiple": self.resolution_multiple,
        }

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        check_input(x, self.in_channels, self.resolution_multiple, "StudentUNet")
        x = self.stem(x)
        skips = []
        for down in self.downs:
            x = down(x)
            skips.append(x)
        for up in self.ups:
            x = up(torch.cat((x, skips.pop()), dim=1))
        return self.head(x)


def build_student(size: str, in_channels: int = 3, out_channels: int = 1) -> StudentUNet:
    """Build a student preset: ``"small"``, ``"medium"`` or ``"large"``."""
    if size not in STUDENT_PRESETS:
        raise ValueError(f"unknown student size {size!r}; valid sizes: {sorted(STUDENT_PRESETS)}")
    model = StudentUNet(in_channels, out_channels, STUDENT_PRESETS[size])
    model.preset = size
    return model
