"""Hd19: EDT Hausdorff equals scipy's directed_hausdorff both ways; blobs and empty predictions count."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial.distance import directed_hausdorff

from spade.metrics.geometry import mask_hausdorff
from spade.metrics.hausdorff import HausdorffCount, Hd19


def scipy_hausdorff(a: np.ndarray, b: np.ndarray) -> float:
    pa, pb = np.argwhere(a).astype(float), np.argwhere(b).astype(float)
    return max(directed_hausdorff(pa, pb)[0], directed_hausdorff(pb, pa)[0])


def test_equals_scipy_directed_hausdorff_both_ways() -> None:
    rng = np.random.default_rng(0)
    for density in (0.002, 0.02, 0.2):
        for _ in range(10):
            a = rng.random((37, 29)) < density
            b = rng.random((37, 29)) < density
            a[rng.integers(37), rng.integers(29)] = True
            b[rng.integers(37), rng.integers(29)] = True
            assert mask_hausdorff(a, b) == pytest.approx(scipy_hausdorff(a, b), rel=1e-12)


def test_empty_masks() -> None:
    a = np.zeros((8, 8), bool)
    b = a.copy()
    b[3, 3] = True
    assert mask_hausdorff(a, b) == np.inf and mask_hausdorff(b, a) == np.inf
    assert mask_hausdorff(a, a) == 0.0


def test_blob_30px_from_the_path_counts_and_empty_prediction_counts() -> None:
    size = 64
    target = torch.zeros(3, 1, size, size)
    target[:, 0, 10, 5:41] = 1.0  # a straight path along row 10
    pred = target.clone() * 0.9
    pred[1, 0, 40:42, 20:22] = 1.0  # instance 1: a disconnected 2 x 2 blob, nearest pixel 30 px from the path
    pred[2] = 0.0  # instance 2: nothing predicted
    metric = Hd19()
    metric.update(pred, target)
    d = metric.per_instance().numpy()
    assert d[0] == 0.0 and np.isinf(d[2])
    assert d[1] == pytest.approx(scipy_hausdorff(pred[1, 0].numpy() >= 0.5, target[1, 0].numpy() > 0.5))
    assert d[1] == 31.0  # the blob's far row: the full mask counts, not only its nearest pixel
    out = metric.compute()
    assert metric.name == "hd19" and out["hd19"].item() == 2 and out["empty"].item() == 1
    assert out["hd19_rate"].item() == pytest.approx(2 / 3)
    assert out["hausdorff_mean_px"].item() == pytest.approx(15.5)
    assert out["hausdorff_median_px"].item() == pytest.approx(15.5)
    clean = HausdorffCount()
    clean.update(pred[:1], target[:1])
    assert clean.compute()["hd19"].item() == 0


def test_threshold_names_and_strictness() -> None:
    target = torch.zeros(1, 1, 16, 16)
    target[0, 0, 2, 2] = 1
    pred = torch.zeros(1, 1, 16, 16)
    pred[0, 0, 2, 12] = 1  # exactly 10 px away
    at10 = HausdorffCount(threshold=10)
    at10.update(pred, target)
    assert at10.name == "hd10" and at10.compute()["hd10"].item() == 0  # "exceeds": strictly greater
    below = HausdorffCount(threshold=9.5)
    below.update(pred, target)
    assert below.name == "hd9.5" and below.compute()["hd9.5"].item() == 1
    soft = HausdorffCount(threshold=10, pred_threshold=0.7)
    soft.update(pred * 0.6, target)
    assert soft.compute()["empty"].item() == 1


def test_empty_target_is_an_error() -> None:
    with pytest.raises(ValueError, match="target_path is empty for batch rows \\[0\\]"):
        Hd19().update(torch.ones(1, 1, 8, 8), torch.zeros(1, 1, 8, 8))
