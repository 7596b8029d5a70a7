"""The planner's search decoder on hand-made probability maps, its figures in PathMetrics, and the U template."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from spade.data.polyline import polyline_length
from spade.metrics.baselines import draw_polyline, heading_template, shape_template, u_template
from spade.metrics.decoding import PathDecoder, decode_path, path_confidence
from spade.metrics.synthetic import rasterise_polyline
from spade.metrics.path_metrics import PathMetrics

H = 64
START = np.array([32.0, 48.0])  # the robot-frame robot pixel at 64 px
GOAL = np.array([54.0, 18.0])
L_PATH = np.array([[32.0, 48.0], [32.0, 18.0], [54.0, 18.0]])  # up, then right: a sharp L


def free_grid() -> np.ndarray:
    return np.ones((H, H), np.uint8)


def band(points: np.ndarray, p: float = 0.95, background: float = 0.01, width: int = 3) -> np.ndarray:
    return np.where(rasterise_polyline(points, (H, H), width), p, background).astype(np.float32)


def distance_to(points: np.ndarray, curve: np.ndarray) -> np.ndarray:
    """Distance of each point to the nearest point of a densely sampled curve."""
    from spade.data.polyline import resample_polyline

    dense = resample_polyline(curve, 400)
    return np.linalg.norm(points[:, None] - dense[None], axis=2).min(axis=1)


def test_start_and_goal_are_the_ends_and_points_are_even() -> None:
    d = decode_path(band(L_PATH), free_grid(), START, GOAL, 0.1, num_points=40)
    assert d.ok and d.points.shape == (40, 2)
    np.testing.assert_allclose(d.points[0], START)
    np.testing.assert_allclose(d.points[-1], GOAL)
    steps = np.linalg.norm(np.diff(d.points, axis=0), axis=1)
    assert steps.max() - steps.min() < 0.02 * steps.mean()  # even by arc length (chords of a curve: nearly)
    assert distance_to(d.points, L_PATH).max() < 2.5  # follows the L (the corner rounded by the smoothing)
    assert d.low_share == 0.0 and d.min_prob == pytest.approx(0.95)


def test_a_gap_in_the_turn_is_bridged_along_the_high_probability_side() -> None:
    """The probability dips below 0.5 mid-turn (what breaks the skeleton extraction); a wide turn survives on one
    side only. The decoded path crosses the gap, ends at the goal and takes the surviving wide side."""
    wide = np.array([[32.0, 48.0], [32.0, 30.0], [36.0, 22.0], [44.0, 18.0], [54.0, 18.0]])
    prob = band(L_PATH, p=0.9)
    prob = np.maximum(prob, band(wide, p=0.7))
    prob[14:27, 26:40] = np.where(rasterise_polyline(wide, (H, H), 3)[14:27, 26:40], 0.7, 0.2)  # sharp corner gone
    prob[22:24, 33:37] = 0.3  # and a gap across the wide turn too
    d = decode_path(prob, free_grid(), START, GOAL, 0.1)
    assert d.ok
    np.testing.assert_allclose(d.points[-1], GOAL)
    mid = d.points[(d.points[:, 1] < 30) & (d.points[:, 0] < 44)]  # the turn
    assert len(mid) > 0
    assert np.median(distance_to(mid, wide)) < np.median(distance_to(mid, L_PATH))
    assert 0 < d.low_share < 0.2 and d.min_prob <= 0.3 + 1e-6


def test_a_blob_away_from_the_path_is_ignored() -> None:
    prob = band(L_PATH)
    prob[50:60, 5:15] = 0.99  # a confident blob behind and to the left of the robot
    d = decode_path(prob, free_grid(), START, GOAL, 0.1)
    assert d.ok and distance_to(d.points, L_PATH).max() < 2.5
    assert not ((d.points[:, 0] < 16) & (d.points[:, 1] > 48)).any()


def test_an_obstacle_in_a_high_probability_corridor_is_routed_around() -> None:
    straight = np.array([[32.0, 48.0], [32.0, 10.0]])
    prob = band(straight)
    grid = free_grid()
    grid[27:31, 29:36] = 2  # a box on the predicted line
    d = decode_path(prob, grid, START, np.array([32.0, 10.0]), 0.1)
    assert d.ok
    cols = np.clip(np.rint(d.points[:, 0]).astype(int), 0, H - 1)
    rows = np.clip(np.rint(d.points[:, 1]).astype(int), 0, H - 1)
    assert (grid[rows, cols] == 1).all()
    dense_cells = np.rint(d.pixels).astype(int)
    assert (grid[dense_cells[:, 1], dense_cells[:, 0]] == 1).all()
    assert (np.abs(d.points[:, 0] - 32) > 3).any()  # it went round the box
    assert d.low_share > 0  # partly through pixels the network did not predict


def test_a_uniform_map_gives_the_shortest_free_path() -> None:
    prob = np.full((H, H), 0.5, np.float32)
    d = PathDecoder(inflation_weight=0.0)(prob, free_grid(), START, GOAL, 0.1)
    assert d.ok and polyline_length(d.points) == pytest.approx(np.linalg.norm(GOAL - START), rel=0.03)
    grid = free_grid()
    grid[0:40, 40] = 2  # a wall the straight line would cross: around its lower end
    d = PathDecoder(inflation_weight=0.0)(prob, grid, START, GOAL, 0.1)
    assert d.ok and d.points[:, 1].max() >= 39.5 - 1e-6 or (d.points[:, 1] > 39).any()
    cells = np.rint(d.pixels).astype(int)
    assert (grid[cells[:, 1], cells[:, 0]] == 1).all()


def test_impossible_queries_fail_with_a_code() -> None:
    grid = free_grid()
    grid[:, 40] = 2  # a wall across the whole window
    assert decode_path(band(L_PATH), grid, START, GOAL, 0.1).failure == "no_free_path"
    grid = free_grid()
    grid[18, 54] = 2
    assert decode_path(band(L_PATH), grid, START, GOAL, 0.1).failure == "goal_blocked"
    assert decode_path(band(L_PATH), free_grid(), np.array([-3.0, 5.0]), GOAL, 0.1).failure == "start_blocked"
    forced = PathDecoder(force_endpoints=True)(band(L_PATH), grid, START, GOAL, 0.1)
    assert forced.ok and np.allclose(forced.points[-1], GOAL)
    with pytest.raises(ValueError, match="one shape"):
        decode_path(np.zeros((H, H)), np.ones((H, 32), np.uint8), START, GOAL, 0.1)


def test_path_confidence_measures_length_share() -> None:
    prob = np.ones((H, H), np.float32)
    prob[:, 40:] = 0.1
    share, pmin = path_confidence(prob, np.array([[20.0, 10.0], [59.0, 10.0]]))
    assert share == pytest.approx(20 / 39, abs=0.02) and pmin == pytest.approx(0.1)


def states_for(paths: list[np.ndarray]) -> dict:
    """A batch of free windows with start/goal discs and ground-truth paths (polylines and their channels)."""
    from skimage.draw import disk

    b = len(paths)
    state = torch.zeros(b, 3, H, H)
    state[:, 0] = 0.5
    path = torch.zeros(b, 1, H, H)
    waypoints = []
    from spade.data.polyline import resample_polyline

    for i, pts in enumerate(paths):
        for ch, xy in ((1, pts[0]), (2, pts[-1])):
            rr, cc = disk((xy[1], xy[0]), 1.5, shape=(H, H))
            state[i, ch, rr, cc] = 1.0
        path[i, 0] = torch.from_numpy(draw_polyline(pts, H, H))
        waypoints.append(resample_polyline(pts, 32))
    return {"state": state, "path": path, "waypoints": torch.tensor(np.stack(waypoints)),
            "resolution": torch.full((b,), 0.1)}


def test_path_metrics_report_the_paper_and_the_planner_figures() -> None:
    """A prediction broken mid-turn: the paper's extraction stops at the break (large APE), the planner's decoded
    path reaches the goal (small APE, flagged low confidence); a baseline's polyline is scored directly."""
    batch = states_for([L_PATH, L_PATH])
    broken = band(L_PATH, p=0.95)
    broken[14:24, 28:40] = 0.3  # no pixel of the corner passes 0.5
    prob = torch.from_numpy(np.stack([band(L_PATH), broken]))[:, None]
    metrics = PathMetrics(fid=False, planner_keys=None)
    metrics.update(prob, batch)
    out = metrics.compute()
    for key in ("ape_cm", "hd19", "failure_rate", "over_20cm_rate", "planner/ape_cm", "planner/hd19",
                "planner/failure_rate", "planner/over_20cm_rate", "planner/low_confidence_rate"):
        assert key in out, key
    # the paper's extraction keeps the first leg of the broken one (over 1 m off); the planner's path is not in the tail
    assert out["ape_max_cm"] > 100.0 and out["over_20cm_rate"] == 0.5
    assert out["planner/ape_max_cm"] < 20.0 and out["planner/over_20cm_rate"] == 0.0
    assert out["planner/ape_cm"] - out["planner/ape_std_cm"] < 5.0  # the intact one: a few cm (corner smoothing)
    assert out["planner/failure_rate"] == 0.0 and out["planner/low_confidence_rate"] == 0.5
    metrics.reset()
    metrics.update(torch.zeros(2, 1, H, H), batch, polylines=[L_PATH, None])
    out = metrics.compute()
    assert out["planner/ape_cm"] == pytest.approx(0.0, abs=1e-6) and out["planner/failure_rate"] == 0.5
    assert out["planner/over_20cm_rate"] == 0.5 and "planner/low_confidence_rate" not in out


def test_u_template_turns_back_to_the_goal() -> None:
    start, goal = np.array([32.0, 48.0]), np.array([42.0, 40.0])  # 1 m to the right, 0.8 m ahead, at 0.1 m/px
    poly = u_template(start, goal, 0.1, tail_m=1.2, window=(H, H))
    np.testing.assert_allclose(poly[0], start)
    np.testing.assert_allclose(poly[-1], goal)
    top = poly[:, 1].min()
    assert top == pytest.approx(48 - 8 - 12 - 5, abs=0.3)  # goal ahead 8 px + a 1.2 m way back, radius 5 px
    assert poly[:, 0].max() == pytest.approx(42.0, abs=1e-6) and poly[:, 0].min() == pytest.approx(32.0, abs=1e-6)
    heading_turn = np.degrees(np.arctan2(*(poly[-1] - poly[-2])[::-1]))  # the last leg runs back down (+y)
    assert heading_turn == pytest.approx(90.0, abs=1e-6)
    near_top = u_template(np.array([32.0, 10.0]), np.array([42.0, 12.0]), 0.1, window=(H, H))
    assert near_top[:, 1].min() >= -1e-6  # the turn stays inside the window
    np.testing.assert_allclose(u_template(start, np.array([32.3, 30.0]), 0.1), [start, [32.3, 30.0]])
    np.testing.assert_allclose(shape_template(start, goal, 0.1, "L"), heading_template(start, goal))
    default = u_template(start, goal, 0.1, window=(H, H))  # U_TAIL_M = 0: the turn starts abreast of the goal
    assert default[:, 1].min() == pytest.approx(48 - 8 - 5, abs=0.3)
    np.testing.assert_allclose(default[-1], goal)
    assert np.linalg.norm(np.diff(default, axis=0), axis=1).min() > 1e-6  # no repeated point at the goal
    np.testing.assert_allclose(shape_template(start, goal, 0.1, "U", (H, H)), default)


def test_decoding_is_deterministic() -> None:
    """The same probabilities give the same path, bit for bit (a resumed run must repeat the planner's figures)."""
    from spade.metrics.synthetic import synthetic_batch, synthetic_predictions
    from spade.metrics.extraction import marker_centre

    batch = synthetic_batch(6, size=H, seed=3, resolution=0.1)
    prob = synthetic_predictions(batch["path"], seed=3)[:, 0]
    decoder = PathDecoder(force_endpoints=True)
    for i in range(6):
        s = batch["state"][i]
        args = (prob[i], np.rint(s[0] * 2).astype(np.uint8), marker_centre(s[1]), marker_centre(s[2]), 0.1)
        a, b = decoder(*args), PathDecoder(force_endpoints=True)(*args)
        assert a.failure == b.failure and a.low_share == b.low_share
        np.testing.assert_array_equal(a.points, b.points)
