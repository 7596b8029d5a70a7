"""``ShapeFeatures``: FID features trained to see the shape of a path (FID's default extractor, ``"shape"``).

Why: a random conv net (:class:`~spade.metrics.features.RandomConvFeatures`) responds mostly to how a path is
drawn (line width, blur, texture), hardly to where it goes: on the quickstart's L test set a straight line
scored ten times closer to the demonstrations than a trained student. These features are the 64-D embedding
of a small CNN trained to recover, from a path image alone, what makes two paths differ:

- the path's geometry: 8 points resampled evenly along it from its start (the robot), its heading at the
  start and at the end (cos, sin), its length (log);
- its turning: the signed heading change in each eighth of its arc length (where and how sharply it turns:
  the turn radius and direction) and in total, and its kind by total turn (straight < 45 deg < L < 135 deg < U);
- breaks: the fraction of its arc length missing (training images had random gaps cut out; others were
  shifted, so that the points are read from the image, not assumed to start at the robot).

Training (``python -m spade.metrics.train_shape_features``, which rebuilds the shipped weights bit for bit on
the same CPU and torch build; see that module for the data, the targets, the epochs and the seconds it took)
uses only the project's own procedural demonstrations: the annotation tool's L and U demonstrations on the
training presets' maps (never the test preset's held-out map), their start-to-goal straight segments, and the
same paths drawn at 128 px. Every image is the one-pixel curve of a dataset's ``path`` channel, so FID on these
features compares path shapes; how a prediction is drawn is the caller's business (draw every predictor's
polyline with :func:`spade.metrics.baselines.draw_polyline`).

It was trained on one-pixel curves only: soft, blurred or thick drawings are outside what it knows, and FID on
them is no measure of anything (the bench's drawing-sensitivity table: 300 synthetic paths blurred with sigma
0.5 scored 3.7, with sigma 1 only 2.7, against 2.3 unblurred). Draw every predictor's path first.

Inputs of any size are first brought to the 64 x 64 grid it was trained on by adaptive max pooling (a 128 px
window at 0.05 m/px covers the same 6.4 m as a 64 px one at 0.1 m/px; a one-pixel curve stays one or two pixels
wide); it was trained for 64 and 128 px robot-frame windows (robot at (W/2, 3W/4), heading up) and is not
meant for others. The last layer is normalised so that each feature has zero mean and unit variance over the
training demonstrations, so FID is in units of those variances. About 5.6 M multiply-adds per image: FID over
2,000 + 2,000 images took 3.8 s at 64 px and 5.0 s at 128 px on one thread of the 2-core development machine
while other jobs loaded it (load average 8; the random conv net: 3.8 s and 10.4 s). The weights (``shape_features_v1.npz``, float32) are pinned by
sha256 over their bytes; ``identity`` carries the version and the hash.
"""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Mapping

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

__all__ = ["ShapeFeatures", "SHAPE_WEIGHTS_FILE", "DEFAULT_SHAPE_SHA256", "SHAPE_VERSION", "weights_sha256"]

SHAPE_VERSION = "shape-v1"
SHAPE_WEIGHTS_FILE = Path(__file__).with_name("shape_features_v1.npz")
# sha256 of the shipped weights (weights_sha256 of SHAPE_WEIGHTS_FILE). Pinned: a change changes every FID, so
# it must be deliberate (retrain with spade.metrics.train_shape_features, bump SHAPE_VERSION, update this pin).
DEFAULT_SHAPE_SHA256 = "22a00b95838ab6230b569576d739a4547f9d285d1236c0b38b93df808957550d"

CANON = 64  # the grid the network sees
WIDTHS = (16, 32, 64, 64)  # four 4x4 stride-2 convolutions: 64 -> 32 -> 16 -> 8 -> 4
HIDDEN = 128
FEATURES = 64


def weights_sha256(arrays: Mapping[str, np.ndarray]) -> str:
    """sha256 over the arrays' names, shapes and little-endian float32 bytes, in name order (not the file's
    bytes, so the container format cannot change it)."""
    digest = hashlib.sha256(SHAPE_VERSION.encode())
    for name in sorted(arrays):
        a = np.ascontiguousarray(np.asarray(arrays[name], dtype="<f4"))
        digest.update(f"|{name}|{a.shape}|".encode())
        digest.update(a.tobytes())
    return digest.hexdigest()


class ShapeNet(nn.Module):
    """The trained network: conv trunk, a hidden layer, the ``FEATURES``-D embedding (and, when training, heads)."""

    def __init__(self, heads: int = 0) -> None:
        super().__init__()
        layers: list[nn.Module] = []
        c_in = 1
        for c_out in WIDTHS:
            layers += [nn.Conv2d(c_in, c_out, 4, stride=2, padding=1), nn.ReLU()]
            c_in = c_out
        self.trunk = nn.Sequential(*layers)
        self.hidden = nn.Linear(WIDTHS[-1] * (CANON // 16) ** 2, HIDDEN)
        self.embed = nn.Linear(HIDDEN, FEATURES)
        self.heads = nn.Linear(FEATURES, heads) if heads else None

    @staticmethod
    def canonical(x: torch.Tensor) -> torch.Tensor:
        """(B, 1, H, W) -> (B, 1, 64, 64) by adaptive max pooling (nearest upsampling below 64 px)."""
        if tuple(x.shape[-2:]) == (CANON, CANON):
            return x
        if min(x.shape[-2:]) < CANON:
            x = F.interpolate(x, size=(max(CANON, x.shape[-2]), max(CANON, x.shape[-1])), mode="nearest")
        return F.adaptive_max_pool2d(x, CANON)

    def features(self, x: torch.Tensor) -> torch.Tensor:
        h = self.trunk(self.canonical(x))
        return self.embed(F.relu(self.hidden(h.flatten(1))))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        f = self.features(x)
        return self.heads(f) if self.heads is not None else f

    def feature_arrays(self) -> dict[str, np.ndarray]:
        """The weights FID needs (no heads), as float32 arrays."""
        return {k: v.detach().cpu().numpy().astype("<f4") for k, v in self.state_dict().items()
                if not k.startswith("heads.")}


class ShapeFeatures(nn.Module):
    """FID's default extractor: the shape-trained embedding, 64 features, weights from the package (pinned).

    Args:
        weights_path: an ``.npz`` written by :mod:`spade.metrics.train_shape_features` (default: the shipped file).
        expected_sha256: the pin (default: :data:`DEFAULT_SHAPE_SHA256` for the shipped file, none for another).
    """

    def __init__(self, weights_path: str | Path | None = None, expected_sha256: str | None = None,
                 in_channels: int = 1) -> None:
        super().__init__()
        if int(in_channels) != 1:
            raise ValueError(f"FID extractor 'shape' reads one-channel path images, not in_channels={in_channels}")
        path = Path(weights_path).expanduser() if weights_path is not None else SHAPE_WEIGHTS_FILE
        if weights_path is None and expected_sha256 is None:
            expected_sha256 = DEFAULT_SHAPE_SHA256
        if not path.is_file():
            raise FileNotFoundError(
                f"FID extractor 'shape': weights file {path} not found; it ships with the package "
                "(spade/metrics/shape_features_v1.npz, see pyproject's package-data); rebuild it with "
                "python -m spade.metrics.train_shape_features"
            )
        try:
            with np.load(path, allow_pickle=False) as data:
                arrays = {k: data[k] for k in data.files}
        except (ValueError, OSError, EOFError) as exc:  # not an .npz of plain arrays (numpy would hint at pickles)
            raise ValueError(f"FID extractor 'shape': {path} is not a weights file (an .npz of plain arrays: "
                             f"{type(exc).__name__}); restore the shipped file, or rebuild it with "
                             "python -m spade.metrics.train_shape_features") from None
        self.sha256 = weights_sha256(arrays)
        if expected_sha256 is not None and self.sha256 != expected_sha256:
            raise RuntimeError(
                f"FID extractor 'shape': {path} hashes to {self.sha256}, not the pinned {expected_sha256}: FID values "
                "would not be comparable with earlier runs. Restore the shipped file, or rebuild it with "
                "python -m spade.metrics.train_shape_features (and bump the version and pin for new weights)."
            )
        expected = {k for k in ShapeNet().state_dict() if not k.startswith("heads.")}
        if set(arrays) != expected:
            raise ValueError(f"FID extractor 'shape': {path} holds arrays {sorted(arrays)}, "
                             f"expected {sorted(expected)}")
        # Non-persistent buffers, not parameters (as RandomConvFeatures): never in an optimiser, and a module that
        # holds a FID metric keeps them out of its checkpoints (they come from the package, pinned).
        self._names = sorted(expected)
        for name in self._names:
            self.register_buffer(name.replace(".", "_"), torch.from_numpy(np.array(arrays[name], dtype=np.float32)),
                                 persistent=False)
        self.in_channels = 1
        self.feature_dim = FEATURES
        self.weights_path = path
        self.identity = f"{SHAPE_VERSION}_c1_D{FEATURES}_sha256-{self.sha256[:12]}"

    def train(self, mode: bool = True) -> ShapeFeatures:  # never trained here: always eval
        super().train(False)
        return self

    @torch.no_grad()
    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if x.ndim != 4 or x.shape[1] != 1:
            raise ValueError(f"expected (B, 1, H, W) images, got {tuple(x.shape)}")
        if min(x.shape[-2:]) < 8:
            raise ValueError(f"images must be at least 8 x 8 pixels, got {tuple(x.shape[-2:])}")
        h = ShapeNet.canonical(x.to(self.embed_weight.device, torch.float32))
        for i in range(len(WIDTHS)):
            h = F.relu(F.conv2d(h, getattr(self, f"trunk_{2 * i}_weight"), getattr(self, f"trunk_{2 * i}_bias"),
                                stride=2, padding=1))
        h = F.relu(F.linear(h.flatten(1), self.hidden_weight, self.hidden_bias))
        return F.linear(h, self.embed_weight, self.embed_bias)
