"""FID: reference agreement, batch-split invariance, sensitivity of the default extractor, clear errors."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy import linalg

from spade.metrics import FID, RandomConvFeatures, build_feature_extractor, frechet_distance
from spade.metrics.features import DEFAULT_RANDCONV_SHA256
from spade.metrics.synthetic import degrade, synthetic_batch

N = 300  # > 240 features + 1
SIZE = 32


@pytest.fixture(scope="module")
def real() -> torch.Tensor:
    return torch.from_numpy(synthetic_batch(N, size=SIZE, seed=1)["path"])


@pytest.fixture(scope="module")
def generated() -> np.ndarray:
    return synthetic_batch(N, size=SIZE, seed=2)["path"]


def scipy_reference(f_real: np.ndarray, f_fake: np.ndarray) -> float:
    """The textbook float64 computation (pytorch-fid's formula) with scipy's sqrtm of the product."""
    mu1, mu2 = f_real.mean(0), f_fake.mean(0)
    s1, s2 = np.cov(f_real, rowvar=False), np.cov(f_fake, rowvar=False)
    covmean = linalg.sqrtm(s1 @ s2)
    diff = mu1 - mu2
    return float(diff @ diff + np.trace(s1) + np.trace(s2) - 2 * np.trace(covmean.real))


def test_default_extractor_is_pinned_and_named() -> None:
    fid = FID()
    assert fid.feature_dim == 240
    assert fid.extractor.sha256 == DEFAULT_RANDCONV_SHA256
    assert fid.identity == f"randconv-v2_c1_16-32-48_g1-1-2_seed0_sha256-{DEFAULT_RANDCONV_SHA256[:12]}"
    assert RandomConvFeatures(seed=1).identity != fid.identity
    assert not list(fid.parameters())  # weights are buffers: never trained, never in an optimiser
    with pytest.raises(RuntimeError, match="not the pinned"):
        RandomConvFeatures(seed=1, expected_sha256=DEFAULT_RANDCONV_SHA256)


def test_fid_of_a_set_with_itself_is_zero(real: torch.Tensor) -> None:
    fid = FID()
    fid.update(real, real=True)
    fid.update(real, real=False)
    value = fid.compute()["fid"].item()
    scale = float(np.trace(fid._gaussian("real")[1]))
    assert abs(value) < 1e-9 * scale


def test_agrees_with_float64_scipy_sqrtm_reference(real: torch.Tensor, generated: np.ndarray) -> None:
    fake = torch.from_numpy(degrade(generated, "blur", 1.0))
    fid = FID()
    fid.update(real, real=True)
    fid.update(fake, real=False)
    ours = fid.compute()["fid"].item()
    f_real = fid.extractor(real).double().numpy()
    f_fake = fid.extractor(fake).double().numpy()
    assert ours == pytest.approx(scipy_reference(f_real, f_fake), rel=1e-6)


def test_frechet_distance_of_known_gaussians() -> None:
    # Commuting covariances: Tr((S1 S2)^(1/2)) = sum sqrt(l1 l2).
    l1, l2 = np.array([1.0, 4.0, 9.0]), np.array([4.0, 1.0, 0.25])
    expected = 3.0 + np.sum(l1 + l2 - 2 * np.sqrt(l1 * l2))
    rot = linalg.qr(np.random.default_rng(0).normal(size=(3, 3)))[0]
    s1, s2 = rot @ np.diag(l1) @ rot.T, rot @ np.diag(l2) @ rot.T
    assert frechet_distance(np.zeros(3), s1, np.ones(3), s2) == pytest.approx(expected, rel=1e-12)


def test_independent_of_batch_split(real: torch.Tensor, generated: np.ndarray) -> None:
    fake = torch.from_numpy(generated)
    whole = FID()
    whole.update(real, real=True)
    whole.update(fake, real=False)
    pieces = FID()
    for start in range(0, N, 37):
        pieces.update(fake[start : start + 37], real=False)
        pieces.update(real[start : start + 37], real=True)
    assert pieces.compute()["fid"].item() == pytest.approx(whole.compute()["fid"].item(), rel=1e-9)


@pytest.mark.parametrize(
    "kind, levels",
    [("shift", [0, 2, 6]), ("blur", [0, 0.7, 1.5]), ("dropout", [0, 0.2, 0.5]), ("blobs", [0, 2, 6])],
)
def test_rises_monotonically_with_degradation(real: torch.Tensor, generated: np.ndarray, kind: str, levels: list) -> None:
    fid = FID()
    fid.update(real, real=True)
    saved = {k: getattr(fid, k).clone() for k in ("real_n", "real_sum", "real_outer")}
    values = []
    for level in levels:
        fid.reset()
        for k, v in saved.items():
            setattr(fid, k, v.clone())
        fid.update(torch.from_numpy(degrade(generated, kind, level, seed=3)), real=False)
        values.append(fid.compute()["fid"].item())
    assert all(b > a for a, b in zip(values, values[1:])), f"FID not increasing for {kind}: {values}"


def test_any_image_size_and_channel_count() -> None:
    ext = RandomConvFeatures(in_channels=4)
    for hw in ((16, 16), (24, 40), (128, 128)):
        assert ext(torch.rand(2, 4, *hw)).shape == (2, ext.feature_dim)
    with pytest.raises(ValueError, match=r"\(B, 4, H, W\)"):
        ext(torch.rand(2, 1, 16, 16))


def test_too_few_samples_names_the_needed_number(real: torch.Tensor) -> None:
    fid = FID()
    fid.update(real[:100], real=True)
    fid.update(real[:300], real=False)
    with pytest.raises(ValueError, match="needs at least 241 real and 241 generated images .*; got 100 real and 300"):
        fid.compute()


def test_inception_option_fails_clearly_without_weights(tmp_path) -> None:
    with pytest.raises(ValueError, match="inception.*inception_v3_google-0cc3c7bd.pth.*download"):
        FID("inception")
    with pytest.raises(FileNotFoundError, match="inception.*not found.*download.pytorch.org"):
        FID("inception", extractor_kwargs={"weights_path": tmp_path / "missing.pth"})
    weights = tmp_path / "inception_v3_google-0cc3c7bd.pth"
    weights.write_bytes(b"not really weights")
    try:
        import torchvision  # noqa: F401
    except ImportError:
        with pytest.raises(ImportError, match="'inception' needs torchvision"):
            FID("inception", extractor_kwargs={"weights_path": weights})
    else:  # torchvision present: the bogus file must be rejected when loading
        with pytest.raises(Exception):
            FID("inception", extractor_kwargs={"weights_path": weights})
    with pytest.raises(ValueError, match="unknown FID feature extractor"):
        build_feature_extractor("vgg")


def test_custom_extractor_needs_identity() -> None:
    with pytest.raises(TypeError, match="'feature_dim'"):
        FID(torch.nn.Flatten())
