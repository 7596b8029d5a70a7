"""APE: agreement with evo (translation part, no alignment), exact shifts, failure accounting."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from spade.data.polyline import resample_polyline
from spade.metrics.ape import APE
from spade.metrics.extraction import extract_path
from spade.metrics.geometry import polyline_ape
from spade.metrics.synthetic import rasterise_polyline, synthetic_batch

evo_metrics = pytest.importorskip("evo.core.metrics")
evo_trajectory = pytest.importorskip("evo.core.trajectory")


def evo_ape(pred: np.ndarray, truth: np.ndarray) -> float:
    """evo's mean APE, translation part, no alignment, on the two polylines resampled to len(truth) points."""
    k = len(truth)

    def path(points: np.ndarray) -> object:
        xyz = np.column_stack([resample_polyline(points, k), np.zeros(k)])
        quat = np.tile([1.0, 0.0, 0.0, 0.0], (k, 1))
        return evo_trajectory.PosePath3D(positions_xyz=xyz, orientations_quat_wxyz=quat)

    metric = evo_metrics.APE(evo_metrics.PoseRelation.translation_part)
    metric.process_data((path(truth), path(pred)))
    return float(metric.get_statistic(evo_metrics.StatisticsType.mean))


def test_polyline_ape_equals_evo_on_random_polylines() -> None:
    rng = np.random.default_rng(0)
    for _ in range(20):
        truth = np.cumsum(rng.normal(size=(rng.integers(3, 9), 2)) * 10, axis=0)
        pred = truth[[0, -1]] + rng.normal(size=(2, 2))
        pred = np.vstack([pred[0], truth[1:-1] + rng.normal(size=(len(truth) - 2, 2)) * 3, pred[1]])
        truth_k = resample_polyline(truth, 50)
        assert polyline_ape(pred, truth_k) == pytest.approx(evo_ape(pred, truth_k), rel=1e-12)


def test_metric_equals_evo_on_extracted_paths() -> None:
    data = synthetic_batch(12, size=48, num_points=24, seed=3, width=2, resolution=0.05)
    metric = APE()
    prob = torch.from_numpy(data["path"]) * 0.8
    metric.update(prob, torch.from_numpy(data["state"]), torch.from_numpy(data["waypoints"]), torch.from_numpy(data["resolution"]))
    expected = []
    for i in range(12):
        res = extract_path(prob[i, 0].numpy(), data["state"][i, 1], data["state"][i, 2], 24)
        expected.append(evo_ape(res.points, data["waypoints"][i]) * 0.05 * 100)
    np.testing.assert_allclose(metric.per_instance().numpy(), expected, rtol=1e-9)
    out = metric.compute()
    assert out["ape_cm"].item() == pytest.approx(np.mean(expected), rel=1e-9)
    assert out["ape_median_cm"].item() == pytest.approx(np.median(expected), rel=1e-9)
    assert out["ape_max_cm"].item() == pytest.approx(np.max(expected), rel=1e-9)
    assert out["ape_std_cm"].item() == pytest.approx(np.std(expected), rel=1e-9)
    assert out["failures"].item() == 0 and out["failure_rate"].item() == 0.0


def _instance(points: np.ndarray, size: int) -> tuple[np.ndarray, np.ndarray]:
    """(1, H, W) path raster and (3, H, W) state with one-pixel start/goal markers of a polyline."""
    state = np.zeros((3, size, size), np.float32)
    state[1, int(points[0, 1]), int(points[0, 0])] = 1.0
    state[2, int(points[-1, 1]), int(points[-1, 0])] = 1.0
    return rasterise_polyline(points, (size, size))[None].astype(np.float32), state


@pytest.mark.parametrize("shift", [(1, 0), (0, 2), (-3, 0), (3, 4)])
@pytest.mark.parametrize(
    "truth, tol_px",
    [
        (np.array([[6.0, 20.0], [34.0, 20.0]]), 1e-9),  # straight: extraction is exact
        (np.array([[6.0, 6.0], [30.0, 30.0]]), 1e-9),  # diagonal: exact too
        (np.array([[8.0, 8.0], [30.0, 8.0], [30.0, 28.0], [12.0, 28.0]]), 0.3),  # U: the skeleton cuts corners
    ],
    ids=["straight", "diagonal", "U"],
)
def test_shift_by_k_pixels_gives_k_times_resolution(shift: tuple[int, int], truth: np.ndarray, tol_px: float) -> None:
    size, res, k = 40, 0.04, 30
    waypoints = resample_polyline(truth, k)
    moved = truth + np.array(shift, dtype=float)
    assert polyline_ape(waypoints + np.array(shift), waypoints) == pytest.approx(np.hypot(*shift), rel=1e-12)
    prob, state = _instance(moved, size)
    for snap in (True, False):
        metric = APE(snap_endpoints=snap)
        metric.update(torch.from_numpy(prob[None]), torch.from_numpy(state[None]), torch.from_numpy(waypoints[None]), res)
        expected_cm = float(np.hypot(*shift)) * res * 100
        assert metric.compute()["ape_cm"].item() == pytest.approx(expected_cm, abs=tol_px * res * 100 + 1e-9)


def test_failures_are_counted_not_dropped() -> None:
    data = synthetic_batch(4, size=32, num_points=16, seed=5)
    prob = torch.from_numpy(data["path"]).clone()
    prob[1] = 0.0  # nothing predicted
    prob[3] = 0.3  # below the threshold everywhere
    metric = APE()
    metric.update(prob, torch.from_numpy(data["state"]), torch.from_numpy(data["waypoints"]), 0.05)
    out = metric.compute()
    assert out["failures"].item() == 2 and out["instances"].item() == 4
    assert out["failure_rate"].item() == pytest.approx(0.5)
    assert metric.per_instance().numel() == 2 and torch.isfinite(out["ape_cm"])
    everything_failed = APE()
    everything_failed.update(prob[[1]], torch.from_numpy(data["state"][[1]]), torch.from_numpy(data["waypoints"][[1]]), 0.05)
    out = everything_failed.compute()
    assert torch.isnan(out["ape_cm"]) and out["failure_rate"].item() == 1.0


def test_bad_inputs_name_the_problem() -> None:
    data = synthetic_batch(2, size=32, num_points=8, seed=1)
    prob, state, wp = (torch.from_numpy(data[k]) for k in ("path", "state", "waypoints"))
    metric = APE()
    with pytest.raises(ValueError, match=r"state must be a \(B, 3, H, W\)"):
        metric.update(prob, state[:, :2], wp, 0.05)
    with pytest.raises(ValueError, match="waypoints must be"):
        metric.update(prob, state, wp[..., :1], 0.05)
    with pytest.raises(ValueError, match="batch sizes differ"):
        metric.update(prob, state[:1], wp, 0.05)
    with pytest.raises(ValueError, match="resolution"):
        metric.update(prob, state, wp, torch.tensor([0.05, 0.05, 0.05]))
