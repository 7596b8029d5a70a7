"""FID between real and generated path images, from float64 running sums (DDP-safe, batch-split invariant)."""

from __future__ import annotations

from contextlib import nullcontext

import numpy as np
import torch
from scipy import linalg
from torch import nn
from torchmetrics import Metric

from spade.metrics._inputs import check_images
from spade.metrics.features import build_feature_extractor

try:  # optional: see _single_blas_thread
    from threadpoolctl import threadpool_limits
except ImportError:  # pragma: no cover - threadpoolctl ships with scikit-learn/mlflow; without it only slower
    threadpool_limits = None

__all__ = ["FID", "frechet_distance"]


def _single_blas_thread():
    """One BLAS thread for the small eigendecompositions.

    Right after torch has run (its OpenMP threads still spin-waiting), a multi-threaded OpenBLAS call competes
    with them for the cores: a 240 x 240 eigh measured 0.7-1.5 s instead of 10-20 ms on the 2-core machine.
    """
    return threadpool_limits(1, user_api="blas") if threadpool_limits is not None else nullcontext()


def _psd_sqrt(s: np.ndarray) -> np.ndarray:
    w, v = linalg.eigh(s)
    return (v * np.sqrt(np.clip(w, 0.0, None))) @ v.T


def frechet_distance(mu_r: np.ndarray, cov_r: np.ndarray, mu_g: np.ndarray, cov_g: np.ndarray) -> float:
    """|mu_r - mu_g|^2 + Tr(S_r + S_g - 2 (S_r S_g)^(1/2)), in float64.

    S_r S_g is not symmetric, but it is similar to the symmetric PSD matrix sqrt(S_r) S_g sqrt(S_r)
    (conjugate by sqrt(S_r)), so Tr((S_r S_g)^(1/2)) is the sum of the square roots of that matrix's (clipped
    non-negative) eigenvalues: two symmetric eigendecompositions, no complex arithmetic, no SVD of the product.
    """
    mu_r, mu_g = np.asarray(mu_r, np.float64), np.asarray(mu_g, np.float64)
    cov_r, cov_g = np.asarray(cov_r, np.float64), np.asarray(cov_g, np.float64)
    with _single_blas_thread():
        root_r = _psd_sqrt(cov_r)
        m = root_r @ cov_g @ root_r
        eig = linalg.eigvalsh((m + m.T) / 2.0)
    tr_covmean = float(np.sqrt(np.clip(eig, 0.0, None)).sum())
    diff = mu_r - mu_g
    return float(diff @ diff + np.trace(cov_r) + np.trace(cov_g) - 2.0 * tr_covmean)


class FID(Metric):
    """Frechet distance between Gaussians fitted to features of real and generated images.

    States are float64 running sums per set (count, feature sum, sum of outer products) reduced with "sum" under
    DDP, so the value does not depend on how the data is split into batches or processes. ``identity`` names
    the feature extractor (and its weights' hash): log it with every value (e.g. as an MLflow param/tag).

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

    is_differentiable = False
    higher_is_better = False
    full_state_update = False

    def __init__(self, feature_extractor: str | nn.Module = "shape", extractor_kwargs: dict | None = None, **kwargs) -> None:
        super().__init__(**kwargs)
        if isinstance(feature_extractor, str):
            feature_extractor = build_feature_extractor(feature_extractor, **(extractor_kwargs or {}))
        for attr in ("feature_dim", "identity"):
            if not hasattr(feature_extractor, attr):
                raise TypeError(f"a FID feature extractor needs a '{attr}' attribute; {type(feature_extractor)} has none")
        self.extractor = feature_extractor
        self.identity: str = str(feature_extractor.identity)
        d = int(feature_extractor.feature_dim)
        self.feature_dim = d
        for prefix in ("real", "fake"):
            self.add_state(f"{prefix}_n", default=torch.tensor(0.0, dtype=torch.float64), dist_reduce_fx="sum")
            self.add_state(f"{prefix}_sum", default=torch.zeros(d, dtype=torch.float64), dist_reduce_fx="sum")
            self.add_state(f"{prefix}_outer", default=torch.zeros(d, d, dtype=torch.float64), dist_reduce_fx="sum")

    def update(self, images: torch.Tensor, real: bool) -> None:
        """images (B, C, H, W) in [0, 1] (C = the extractor's channels, 1 for path images); real: which set."""
        check_images(images, "images", getattr(self.extractor, "in_channels", None))
        feats = self.extractor(images).detach().to(self.real_sum.device, torch.float64)
        if feats.ndim != 2 or feats.shape[1] != self.feature_dim:
            raise ValueError(f"extractor returned features of shape {tuple(feats.shape)}, expected (B, {self.feature_dim})")
        prefix = "real" if real else "fake"
        setattr(self, f"{prefix}_n", getattr(self, f"{prefix}_n") + feats.shape[0])
        setattr(self, f"{prefix}_sum", getattr(self, f"{prefix}_sum") + feats.sum(0))
        setattr(self, f"{prefix}_outer", getattr(self, f"{prefix}_outer") + feats.T @ feats)

    def _gaussian(self, prefix: str) -> tuple[np.ndarray, np.ndarray]:
        n = float(getattr(self, f"{prefix}_n"))
        s = getattr(self, f"{prefix}_sum").cpu().numpy()
        outer = getattr(self, f"{prefix}_outer").cpu().numpy()
        mu = s / n
        cov = (outer - n * np.outer(mu, mu)) / (n - 1.0)
        return mu, (cov + cov.T) / 2.0

    def compute(self) -> dict[str, torch.Tensor]:
        n_real, n_fake = int(self.real_n), int(self.fake_n)
        need = self.feature_dim + 1
        if n_real < need or n_fake < need:
            raise ValueError(
                f"FID with extractor {self.identity} ({self.feature_dim} features) needs at least {need} real and "
                f"{need} generated images for full-rank covariances; got {n_real} real and {n_fake} generated. "
                "Compute it over the whole test set, or use an extractor with fewer features."
            )
        fid = frechet_distance(*self._gaussian("real"), *self._gaussian("fake"))
        return {
            "fid": torch.tensor(fid, dtype=torch.float64),
            "fid_real_count": torch.tensor(n_real),
            "fid_fake_count": torch.tensor(n_fake),
        }
