"""The metrics that see a preference (floor, APE over floor, plausibility, commitment) on hand-made cases."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from spade.data.polyline import resample_polyline
from spade.metrics.baselines import draw_polylines
from spade.metrics.geometry import polyline_ape
from spade.metrics.path_metrics import PathMetrics
from spade.metrics.preference import PreferenceMetrics, floor_path, plausible_set

K = 16
RES = 0.1  # metres per pixel: 1 px = 10 cm


def turn(radius: float, k: int = K) -> np.ndarray:
    """A 90-degree path in window pixels from the robot (32, 48) up and then right to (48, 32) - radius.. a corner
    rounded with ``radius`` pixels, resampled to ``k`` points."""
    from spade.data.polyline import resample_polyline

    corner = np.array([32.0, 32.0])
    leg = np.stack([np.full(50, 32.0), np.linspace(48, corner[1] + radius, 50)], axis=1)
    phi = np.linspace(0, np.pi / 2, 50)
    arc = np.stack([corner[0] + radius - radius * np.cos(phi), corner[1] + radius - radius * np.sin(phi)], axis=1)
    tail = np.stack([np.linspace(corner[0] + radius, 48, 50), np.full(50, 32.0)], axis=1)
    return resample_polyline(np.concatenate([leg, arc, tail]), k)


def state_for(goal_xy: tuple[int, int], size: int = 64) -> torch.Tensor:
    """A (3, size, size) state with one free map, the robot disc at (32, 48) and a 3 x 3 goal disc at goal_xy."""
    state = torch.zeros(3, size, size)
    state[0] = 0.5
    state[1, 47:50, 31:34] = 1
    x, y = goal_xy
    state[2, y - 1:y + 2, x - 1:x + 2] = 1
    return state


def batch_of(demos: list[np.ndarray], alternatives: list[list[np.ndarray]], slots: int = 4) -> dict:
    alts = torch.full((len(demos), slots, K, 2), float("nan"))
    for i, rows in enumerate(alternatives):
        for j, a in enumerate(rows):
            alts[i, j] = torch.as_tensor(a)
    states = torch.stack([state_for((int(round(d[-1, 0])), int(round(d[-1, 1])))) for d in demos])
    return {"state": states, "waypoints": torch.as_tensor(np.stack(demos), dtype=torch.float32),
            "alternatives": alts, "resolution": torch.full((len(demos),), RES),
            "path": draw_polylines(demos, 64, 64, torch.device("cpu"))}


def test_prediction_equal_to_an_alternative_is_plausible_and_commits() -> None:
    sharp, wide = turn(3.0), turn(9.0)
    m = PreferenceMetrics(commit_tol_cm=15.0)
    b = batch_of([sharp], [[wide]])
    m.update([wide], b["state"], b["waypoints"], b["alternatives"], b["resolution"])
    out = m.compute()
    assert float(out["plausibility_cm"]) == pytest.approx(0.0, abs=1e-4)
    assert float(out["commit_rate"]) == 1.0
    # its APE against the demonstration is the sharp-wide distance (as the APE metric computes it), not 0
    ape = polyline_ape(wide, sharp) * RES * 100
    assert ape > 5
    assert float(out["ape_over_floor"]) == pytest.approx(ape / float(out["floor_cm"]), rel=1e-5)


def test_the_blend_of_two_turns_is_implausible_and_does_not_commit() -> None:
    sharp, wide = turn(2.0), turn(15.0)
    blend = (sharp + wide) / 2
    m = PreferenceMetrics(commit_tol_cm=5.0)
    b = batch_of([sharp], [[wide]])
    m.update([blend], b["state"], b["waypoints"], b["alternatives"], b["resolution"])
    out = m.compute()
    to_each = [polyline_ape(blend, p) for p in (sharp, wide)]
    assert float(out["plausibility_cm"]) == pytest.approx(min(to_each) * RES * 100, rel=1e-5)
    assert min(to_each) * RES * 100 > 5.0 and float(out["commit_rate"]) == 0.0


def test_floor_with_alternatives_equal_to_the_demonstration_is_its_encoding_error() -> None:
    demo = turn(5.0)
    demo[-1] += np.array([0.4, -0.3])  # the goal off its pixel centre, as a rotated window puts it
    m = PreferenceMetrics()
    b = batch_of([demo], [[demo.copy(), demo.copy()]])
    m.update([demo], b["state"], b["waypoints"], b["alternatives"], b["resolution"])
    centre = np.array([round(demo[-1, 0]), round(demo[-1, 1])], dtype=float)
    ramp = np.linspace(0, 1, K)[:, None]
    expected = np.linalg.norm(ramp * (centre - demo[-1]), axis=1).mean() * RES * 100  # hand: |offset| x mean ramp
    assert expected == pytest.approx(np.hypot(0.4, 0.3) * 0.5 * RES * 100, rel=1e-9)
    assert float(m.compute()["floor_cm"]) == pytest.approx(expected, rel=1e-5)


def test_floor_path_is_the_pointwise_median_ramped_to_the_goal_centre() -> None:
    paths = np.stack([turn(3.0), turn(6.0), turn(9.0)])
    goal = paths[1, -1] + np.array([0.2, 0.0])
    out = floor_path(paths, goal)
    assert np.allclose(out[0], np.median(paths, axis=0)[0])  # the robot stays put
    assert np.allclose(out[-1], goal)  # the end on the disc's centre
    assert np.allclose(out[K // 2], np.median(paths, axis=0)[K // 2] + (K // 2) / (K - 1) * np.array([0.2, 0.0]))


def test_ratio_of_means_failures_and_instances_without_alternatives() -> None:
    sharp, wide, mid = turn(3.0), turn(12.0), turn(7.0)
    b = batch_of([sharp, sharp, wide], [[wide, mid], [], [sharp]])
    m = PreferenceMetrics()
    # instance 0 predicted, instance 1 has no alternatives (left out), instance 2 failed
    m.update([mid, mid, None], b["state"], b["waypoints"], b["alternatives"], b["resolution"])
    out = m.compute()
    assert int(out["pref_instances"]) == 2  # instances 0 and 2
    ape0 = polyline_ape(mid, sharp) * RES * 100

    def floor(demo: np.ndarray, alts: np.ndarray) -> float:
        paths = np.stack([resample_polyline(p, K) for p in [demo, *alts]])
        return float(np.linalg.norm(floor_path(paths, np.round(demo[-1])) - paths[0], axis=1).mean()) * RES * 100

    floor0, floor2 = floor(sharp, [wide, mid]), floor(wide, [sharp])
    assert float(out["floor_cm"]) == pytest.approx((floor0 + floor2) / 2, rel=1e-6)
    assert float(out["ape_over_floor"]) == pytest.approx(ape0 / floor0, rel=1e-5)  # over the scored instance
    assert float(out["commit_rate"]) == pytest.approx(0.5)  # mid equals an alternative; the failure never commits
    assert float(out["plausibility_cm"]) == pytest.approx(0.0, abs=1e-4)


def test_states_merge_as_under_ddp() -> None:
    """Two processes' states merged give the figures of one process that saw every instance."""
    demos = [turn(3.0), turn(12.0), turn(6.0), turn(9.0)]
    alts = [[turn(12.0)], [turn(3.0), turn(6.0)], [turn(9.0)], [turn(3.0)]]
    preds = [turn(7.0), turn(4.0), None, turn(10.0)]
    b = batch_of(demos, alts)
    whole = PreferenceMetrics()
    whole.update(preds, b["state"], b["waypoints"], b["alternatives"], b["resolution"])
    halves = [PreferenceMetrics(), PreferenceMetrics()]
    for part, sl in zip(halves, (slice(0, 2), slice(2, 4))):
        part.update(preds[sl], b["state"][sl], b["waypoints"][sl], b["alternatives"][sl], b["resolution"][sl])
    halves[0].merge_state(halves[1])
    a, c = whole.compute(), halves[0].compute()
    for key in a:
        assert float(a[key]) == pytest.approx(float(c[key]), rel=1e-9), key


def test_path_metrics_report_them_only_where_the_batch_has_alternatives() -> None:
    sharp, wide = turn(3.0), turn(12.0)
    b = batch_of([sharp, wide], [[wide], [sharp]])
    metrics = PathMetrics(fid=False)
    polys = [sharp, wide]
    metrics.update(draw_polylines(polys, 64, 64, torch.device("cpu")), b, polylines=polys)
    out = metrics.compute()
    for key in ("floor_cm", "ape_over_floor", "plausibility_cm", "commit_rate", "planner/ape_over_floor",
                "planner/plausibility_cm", "planner/commit_rate"):
        assert key in out and np.isfinite(out[key]), key
    assert out["planner/plausibility_cm"] == pytest.approx(0.0, abs=1e-4)  # the demonstrations themselves
    assert out["planner/commit_rate"] == 1.0
    del b["alternatives"]
    plain = PathMetrics(fid=False)
    plain.update(draw_polylines(polys, 64, 64, torch.device("cpu")), b, polylines=polys)
    assert not any(k.endswith(("floor_cm", "plausibility_cm", "commit_rate", "ape_over_floor"))
                   for k in plain.compute())


def test_bad_tolerance_is_refused() -> None:
    with pytest.raises(ValueError, match="commit_tol_cm"):
        PreferenceMetrics(commit_tol_cm=0)


def test_spread_of_two_samples_against_the_generators_by_hand() -> None:
    import torch

    from spade.metrics.preference import SpreadMetrics

    line = np.stack([np.linspace(10, 10, 8), np.linspace(30, 10, 8)], axis=1)  # 8 points up the window
    waypoints = torch.tensor(np.stack([line, line]), dtype=torch.float32)
    alts = np.full((2, 2, 8, 2), np.nan)
    alts[0, 0] = line + [4.0, 0.0]  # instance 0: one alternative 4 px to the side
    m = SpreadMetrics()
    m.update([line, line + [1.0, 0.0]], [line + [2.0, 0.0], None], waypoints, torch.tensor(alts, dtype=torch.float32),
             0.05)
    out = {k: float(v) for k, v in m.compute().items()}
    assert out["spread_cm"] == pytest.approx(10.0)  # 2 px at 5 cm; instance 1 lost a sample: left out
    assert out["generator_spread_cm"] == pytest.approx(20.0)  # demonstration vs its one alternative: 4 px
    assert out["spread_ratio"] == pytest.approx(0.5)
    empty = SpreadMetrics()
    empty.update([line], [line], waypoints[:1], None, 0.05)
    got = empty.compute()
    assert float(got["spread_cm"]) == 0.0 and np.isnan(float(got["generator_spread_cm"]))
