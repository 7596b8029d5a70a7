"""FID between real and generated path images: torchmetrics' ``FrechetInceptionDistance`` with SPADE's extractors.

torchmetrics keeps the statistics as float64 running sums (count, feature sum, sum of outer products) reduced with
"sum" under DDP, so the value does not depend on how the data is split into batches or processes. SPADE adds the
extractor (a named, versioned one: :func:`~spade.metrics.features.build_feature_extractor`), its ``identity`` and the
refusal of sets too small for full-rank covariances. Its values agree with the symmetric float64 formula
(Tr((S_r S_g)^(1/2)) from the eigenvalues of sqrt(S_r) S_g sqrt(S_r)) within 2e-9 of the covariance's trace on the
shape and random conv extractors, e.g. 45.52260081 against 45.52260053 (``tests/test_metrics_fid.py`` pins both that
agreement and the one with scipy's float64 ``sqrtm``).
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn
from torchmetrics.image.fid import FrechetInceptionDistance, _compute_fid

from spade.metrics._inputs import check_images
from spade.metrics.features import build_feature_extractor

__all__ = ["FID", "frechet_distance"]


def frechet_distance(mu_r: np.ndarray, cov_r: np.ndarray, mu_g: np.ndarray, cov_g: np.ndarray) -> float:
    """|mu_r - mu_g|^2 + Tr(S_r + S_g - 2 (S_r S_g)^(1/2)) in float64, by torchmetrics' formula (the one
    :class:`FID` computes)."""
    t = [torch.as_tensor(np.asarray(a, np.float64)) for a in (mu_r, cov_r, mu_g, cov_g)]
    return float(_compute_fid(*t))


class _Float64Features(nn.Module):
    """An extractor's features, checked and in float64: torchmetrics casts the FID to the features' dtype."""

    def __init__(self, extractor: nn.Module) -> None:
        super().__init__()
        self.extractor = extractor
        self.num_features = int(extractor.feature_dim)

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        check_images(images, "images", getattr(self.extractor, "in_channels", None))
        feats = self.extractor(images)
        if feats.ndim != 2 or feats.shape[1] != self.num_features:
            raise ValueError(f"extractor returned features of shape {tuple(feats.shape)}, "
                             f"expected (B, {self.num_features})")
        return feats.detach().double()


class FID(FrechetInceptionDistance):
    """Frechet distance between Gaussians fitted to features of real and generated images.

    ``identity`` names the feature extractor (and its weights' hash): log it with every value (e.g. as an MLflow
    param/tag). ``reset_real_features=False`` keeps the real statistics over :meth:`reset` (one real set scored
    against several generated ones).

    Args:
        feature_extractor: "shape" (default: :class:`~spade.metrics.shape_features.ShapeFeatures`, 64 features
            trained on the project's demonstrations to see path shape, weights shipped with the package and
            pinned), "randconv" (fixed random conv net, 240 features), "inception" (torchvision InceptionV3 from
            a local ``weights_path``), or any ``nn.Module`` with ``feature_dim`` and ``identity`` attributes
            mapping (B, C, H, W) to (B, D). Feed it path images drawn alike for real and generated sets (every
            predictor's polyline drawn as the ground truth's path channel is,
            :func:`spade.metrics.baselines.draw_polyline`): FID compares what the features see.
        extractor_kwargs: passed to :func:`~spade.metrics.features.build_feature_extractor` for a named extractor.
    """

    def __init__(self, feature_extractor: str | nn.Module = "shape", extractor_kwargs: dict | None = None,
                 **kwargs) -> None:
        if isinstance(feature_extractor, str):
            feature_extractor = build_feature_extractor(feature_extractor, **(extractor_kwargs or {}))
        for attr in ("feature_dim", "identity"):
            if not hasattr(feature_extractor, attr):
                raise TypeError(f"a FID feature extractor needs a '{attr}' attribute; {type(feature_extractor)} has none")
        super().__init__(feature=_Float64Features(feature_extractor), **kwargs)
        self.identity: str = str(feature_extractor.identity)
        self.feature_dim = int(feature_extractor.feature_dim)

    @property
    def extractor(self) -> nn.Module:
        return self.inception.extractor

    @property
    def real_n(self) -> int:
        return int(self.real_features_num_samples)

    @property
    def fake_n(self) -> int:
        """Generated images seen (on this process until :meth:`compute` syncs)."""
        return int(self.fake_features_num_samples)

    def _gaussian(self, prefix: str) -> tuple[np.ndarray, np.ndarray]:
        """(mean, covariance) of the ``real`` or ``fake`` features seen, in float64."""
        n = float(getattr(self, f"{prefix}_features_num_samples"))
        mu = getattr(self, f"{prefix}_features_sum").cpu().numpy() / n
        outer = getattr(self, f"{prefix}_features_cov_sum").cpu().numpy()
        cov = (outer - n * np.outer(mu, mu)) / (n - 1.0)
        return mu, (cov + cov.T) / 2.0

    def compute(self) -> dict[str, torch.Tensor]:  # type: ignore[override]
        n_real, n_fake = self.real_n, self.fake_n
        need = self.feature_dim + 1
        if n_real < need or n_fake < need:
            raise ValueError(
                f"FID with extractor {self.identity} ({self.feature_dim} features) needs at least {need} real and "
                f"{need} generated images for full-rank covariances; got {n_real} real and {n_fake} generated. "
                "Compute it over the whole test set, or use an extractor with fewer features."
            )
        return {
            "fid": super().compute().double(),
            "fid_real_count": torch.tensor(n_real),
            "fid_fake_count": torch.tensor(n_fake),
        }
