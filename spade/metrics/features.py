"""Feature extractors for FID: ``shape`` (the default: a small CNN trained on the project's demonstrations to see
path shape, :mod:`spade.metrics.shape_features`), a fixed, content-hashed random conv net and InceptionV3.

Every extractor is an ``nn.Module`` mapping (B, C, H, W) images in [0, 1] to (B, D) float features, with the
attributes ``feature_dim`` (D), ``in_channels`` and ``identity`` (a string naming the extractor and the sha256
of its weights; FID values are comparable only between runs whose identities are equal, so log it with them).

Why not a random conv net by default (it was until shape-v1): with like-for-like rendering it does respond to
shape, but mostly to how a path is drawn (line width, blur, texture); the trained ``shape`` features separate
straight lines, U's, sharp corners and broken paths from L demonstrations by one to two orders of magnitude
more than disjoint samples of the demonstrations differ (tests/test_metrics_fid.py,
``python -m spade.bench sections=[metrics] metrics.sensitivity=true``). No offline machine holds ImageNet
Inception weights. The random conv net stays available as ``randconv``: random-weight conv features are a
known, workable FID embedding (Naeem et al., ICML 2020, "Reliable fidelity and diversity metrics"), cost
nothing to obtain, and are bit-identical everywhere: the weights come from NumPy's legacy ``RandomState``
stream, whose output NumPy guarantees never to change, and their sha256 is pinned so that a drift would raise
instead of silently changing every FID. Its sensitivity (FID rising monotonically with shift, blur,
dropout and stray blobs) is measured by ``python -m spade.bench sections=[metrics] metrics.sensitivity=true``
and the tests.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from spade.utils.hashing import file_sha256
from spade.metrics.shape_features import ShapeFeatures

__all__ = [
    "RandomConvFeatures",
    "InceptionFeatures",
    "build_feature_extractor",
    "FEATURE_EXTRACTORS",
    "INCEPTION_WEIGHTS_FILE",
    "INCEPTION_WEIGHTS_URL",
]

INCEPTION_WEIGHTS_FILE = "inception_v3_google-0cc3c7bd.pth"
INCEPTION_WEIGHTS_URL = f"https://download.pytorch.org/models/{INCEPTION_WEIGHTS_FILE}"

# sha256 of the default RandomConvFeatures weights (randconv-v2, seed 0, widths (16, 32, 48), grids (1, 1, 2),
# 1 channel). Pinned: a change here changes every FID, so it must be deliberate (and bump the version).
DEFAULT_RANDCONV_SHA256 = "e0de3ea15012f7eee992fe97c09899a7269527eaa5b8387c22052ac183118439"


class RandomConvFeatures(nn.Module):
    """Three 4x4 stride-2 conv + ReLU stages with fixed random (He-normal) weights and no bias.

    Features: each stage's activations average-pooled to a ``grids[s] x grids[s]`` grid, concatenated. Global
    pools (grid 1) describe texture (line width, blur, blobs, dropout); the coarse grid of the last stage keeps
    where the path lies (shifts). Adaptive pooling makes it work for any H, W (>= 8). Strided convolutions
    keep it cheap (about 1 ms per 128 x 128 image on one CPU core) while every pixel is seen (kernel 4 > stride 2). Default D = 16 + 32 + 4*48
    = 240, so that a few hundred samples already give a full-rank covariance.

    The weights are buffers (not parameters): the extractor never shows up in an optimiser or a checkpoint and
    is regenerated, identical, from its seed.
    """

    def __init__(
        self,
        in_channels: int = 1,
        widths: tuple[int, ...] = (16, 32, 48),
        grids: tuple[int, ...] = (1, 1, 2),
        seed: int = 0,
        expected_sha256: str | None = None,
    ) -> None:
        super().__init__()
        if len(widths) != len(grids) or not widths:
            raise ValueError(f"widths {widths} and grids {grids} must be non-empty and of the same length")
        self.in_channels = int(in_channels)
        self.widths = tuple(int(w) for w in widths)
        self.grids = tuple(int(g) for g in grids)
        self.seed = int(seed)
        rng = np.random.RandomState(self.seed)  # legacy stream: frozen by NumPy's compatibility policy
        digest = hashlib.sha256(f"randconv-v2|{self.in_channels}|{self.widths}|{self.grids}".encode())
        c_in = self.in_channels
        for i, c_out in enumerate(self.widths):
            fan_in = c_in * 16
            w = (rng.standard_normal((c_out, c_in, 4, 4)) * np.sqrt(2.0 / fan_in)).astype("<f4")
            digest.update(w.tobytes())
            self.register_buffer(f"weight{i}", torch.from_numpy(w), persistent=False)
            c_in = c_out
        self.sha256 = digest.hexdigest()
        if expected_sha256 is not None and self.sha256 != expected_sha256:
            raise RuntimeError(
                f"RandomConvFeatures weights hash to {self.sha256}, not the pinned {expected_sha256}: FID values "
                "would not be comparable with earlier runs. Check the NumPy installation (RandomState stream)."
            )
        self.feature_dim = sum(w * g * g for w, g in zip(self.widths, self.grids))
        arch = "-".join(map(str, self.widths)) + "_g" + "-".join(map(str, self.grids))
        self.identity = f"randconv-v2_c{self.in_channels}_{arch}_seed{self.seed}_sha256-{self.sha256[:12]}"

    @torch.no_grad()
    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if x.ndim != 4 or x.shape[1] != self.in_channels:
            raise ValueError(f"expected (B, {self.in_channels}, H, W) images, got {tuple(x.shape)}")
        if min(x.shape[-2:]) < 8:
            raise ValueError(f"images must be at least 8 x 8 pixels, got {tuple(x.shape[-2:])}")
        h = x.to(self.weight0.device, torch.float32)
        feats = []
        for i, grid in enumerate(self.grids):
            h = F.relu(F.conv2d(h, getattr(self, f"weight{i}"), stride=2, padding=1))
            feats.append(F.adaptive_avg_pool2d(h, grid).flatten(1))
        return torch.cat(feats, dim=1)


class InceptionFeatures(nn.Module):
    """torchvision's InceptionV3 pool features (2048-D) from a local ImageNet weights file.

    Images are repeated to 3 channels, resized to 299 x 299 (bilinear) and normalised with ImageNet statistics.
    These are torchvision's weights, not the TF-ported ones of pytorch-fid / the original FID, so values are
    comparable between runs using the same file (see ``identity``), not with published FIDs.
    """

    def __init__(self, weights_path: str | Path | None = None, in_channels: int = 1) -> None:
        super().__init__()
        how = (
            f"download {INCEPTION_WEIGHTS_URL} on a machine with internet access, copy it here and pass its path "
            "as weights_path (feature_extractor='inception', weights_path=...), or use the default offline "
            "extractor feature_extractor='shape'"
        )
        if weights_path is None:
            raise ValueError(f"FID feature extractor 'inception' needs the local weights file {INCEPTION_WEIGHTS_FILE}: {how}")
        path = Path(weights_path).expanduser()
        if not path.is_file():
            raise FileNotFoundError(
                f"FID feature extractor 'inception': weights file {path} not found (expected torchvision's "
                f"{INCEPTION_WEIGHTS_FILE}): {how}"
            )
        try:
            from torchvision.models import inception_v3  # lazy: torchvision is optional
        except ImportError as err:
            raise ImportError(
                "FID feature extractor 'inception' needs torchvision, which is not installed (it must match "
                "torch's build; PyPI's wheel does not fit this project's torch 2.13.0). Install a matching "
                "torchvision, or use the default offline extractor feature_extractor='shape'."
            ) from err
        model = inception_v3(weights=None, aux_logits=True, init_weights=False)
        model.load_state_dict(torch.load(path, map_location="cpu", weights_only=True))
        model.fc = nn.Identity()
        model.eval().requires_grad_(False)
        self.model = model
        self.in_channels = int(in_channels)
        self.feature_dim = 2048
        self.sha256 = file_sha256(path)
        self.identity = f"inception_v3-torchvision_sha256-{self.sha256[:12]}"
        self.register_buffer("mean", torch.tensor([0.485, 0.456, 0.406]).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("std", torch.tensor([0.229, 0.224, 0.225]).view(1, 3, 1, 1), persistent=False)

    def train(self, mode: bool = True) -> InceptionFeatures:  # always in eval mode (batch norm statistics fixed)
        super().train(False)
        return self

    @torch.no_grad()
    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if x.ndim != 4 or x.shape[1] not in (1, 3):
            raise ValueError(f"expected (B, 1 or 3, H, W) images, got {tuple(x.shape)}")
        x = x.to(self.mean.device, torch.float32)
        if x.shape[1] == 1:
            x = x.repeat(1, 3, 1, 1)
        x = F.interpolate(x, size=(299, 299), mode="bilinear", align_corners=False)
        return self.model((x - self.mean) / self.std)


FEATURE_EXTRACTORS = ("shape", "randconv", "inception")
"""The named FID extractors; ``shape`` is FID's default."""


def build_feature_extractor(name: str = "shape", **kwargs) -> nn.Module:
    """Make a FID feature extractor by name: "shape" (default: :class:`~spade.metrics.shape_features.ShapeFeatures`,
    trained to see path shape, weights shipped and pinned), "randconv" (fixed random conv net) or "inception"
    (weights_path=...)."""
    if name == "shape":
        return ShapeFeatures(**kwargs)
    if name == "randconv":
        defaults = not kwargs or set(kwargs) <= {"in_channels"} and kwargs.get("in_channels", 1) == 1
        if defaults:
            kwargs = dict(kwargs, expected_sha256=DEFAULT_RANDCONV_SHA256)
        return RandomConvFeatures(**kwargs)
    if name == "inception":
        return InceptionFeatures(**kwargs)
    raise ValueError(f"unknown FID feature extractor {name!r}; use 'shape' (default), 'randconv' or 'inception'")
