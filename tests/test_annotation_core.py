"""Unit tests of the annotation tool's parts on hand-made grids (no map loading, no dataset writing)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from omegaconf import OmegaConf

from spade.annotation.invariants import instance_problems
from spade.annotation.execution import Rejection, execute_sketch, total_turn_deg
from spade.annotation.scenarios import NoFreeAreaError, generate_scenario, prepare_map, scenario_rng
from spade.annotation.sketch_file import densify
from spade.annotation.templates import SHAPES, UnknownShapeError, check_shape, place_template, sample_template
from spade.data.rasterize import draw_curve, robot_instance, state_indices
from spade.maps.costmap import build_costmap
from spade.maps.frame import RobotFrame, heading_from_yaw, path_heading, yaw_from_heading

CONF = Path(__file__).resolve().parents[1] / "conf" / "annotate.yaml"


def base_cfg() -> dict:
    cfg = OmegaConf.to_container(OmegaConf.load(CONF), resolve=False)
    cfg.pop("defaults", None)
    cfg.pop("hydra", None)
    return cfg


def room(h: int = 200, w: int = 220) -> np.ndarray:
    """A walled room at 0.05 m/px with a wall segment, a pillar and an unknown corner."""
    g = np.ones((h, w), np.uint8)
    g[[0, -1], :] = 2
    g[:, [0, -1]] = 2
    g[60:66, 30:150] = 2
    g[120:140, 150:160] = 2
    g[:30, :30] = 0
    return g


@pytest.mark.parametrize("shape", ["L", "U"])
def test_template_turns_by_the_shape_angle_and_ends_on_goal(shape: str) -> None:
    cfg = base_cfg()["template"]
    for seed in range(20):
        t = sample_template(shape, cfg, np.random.default_rng(seed))
        assert abs(abs(total_turn_deg(t.dense / 0.05 * [1, -1], 2)) - SHAPES[shape]) < 1.0
        kp, dense = place_template(t, np.array([50.0, 60.0]), 0.05)
        np.testing.assert_allclose(kp[-1], [50.0, 60.0], atol=1e-9)
        np.testing.assert_allclose(dense[-1], [50.0, 60.0], atol=1e-9)
        leg = cfg[shape]["leg_m"]
        assert leg[0] <= t.leg_m <= leg[1]


def test_template_variations_cover_mirror_radius_tail_heading() -> None:
    cfg = base_cfg()["template"]
    ts = [sample_template("L", cfg, np.random.default_rng(s)) for s in range(200)]
    assert {t.mirror for t in ts} == {True, False}
    sharp_hi, wide_lo = cfg["L"]["radius_m"]["sharp"][1], cfg["L"]["radius_m"]["wide"][0]
    assert any(t.radius_m <= sharp_hi for t in ts) and any(t.radius_m >= wide_lo for t in ts)
    small_hi, large_lo = cfg["L"]["tail_m"]["small"][1], cfg["L"]["tail_m"]["large"][0]
    assert any(t.tail_m <= small_hi for t in ts) and any(t.tail_m >= large_lo for t in ts)
    headings = np.rad2deg([t.heading_rad for t in ts])
    assert np.histogram(headings, bins=8, range=(0, 360))[0].min() > 0  # not only the four axes


def test_unknown_shape_is_refused_with_the_known_ones() -> None:
    with pytest.raises(UnknownShapeError, match=r"'Z'.*\['L', 'U'\]"):
        check_shape("Z")


def test_costmap_is_lethal_within_robot_radius_and_cheaper_far_away() -> None:
    cfg = base_cfg()
    cm = build_costmap(room(), 0.05, cfg["robot"], 4.0)
    assert np.isinf(cm.cost[61, 80]) and np.isinf(cm.cost[67, 80])  # obstacle, and 1 px from it
    assert np.isfinite(cm.cost[100, 100])
    assert cm.cost[72, 80] > cm.cost[100, 80] >= 1.0


def test_execution_bends_around_an_obstacle_between_waypoints() -> None:
    cfg = base_cfg()
    g = np.ones((120, 200), np.uint8)
    g[[0, -1], :] = 2
    g[:, [0, -1]] = 2
    g[40:80, 95:105] = 2  # a block in the straight line between the waypoints
    cm = build_costmap(g, 0.05, cfg["robot"], 4.0)
    kp = np.array([[20.0, 60.0], [180.0, 60.0]])
    ex_cfg = {**cfg["execution"], "max_deviation_m": 10.0, "shape_tolerance_deg": 360.0}
    ex = execute_sketch(cm, kp, kp, 0.0, ex_cfg)
    cells = np.rint(ex.points).astype(int)
    assert (g[cells[:, 1], cells[:, 0]] == 1).all()
    assert np.abs(ex.points[:, 1] - 60).max() > 20 / 1  # went around the block
    assert ex.min_clearance_m >= cfg["robot"]["radius_m"]
    np.testing.assert_allclose(ex.points[[0, -1]], kp, atol=1e-6)
    steps = np.linalg.norm(np.diff(ex.points, axis=0), axis=1)
    assert np.allclose(steps, steps.mean(), rtol=0.05)  # evenly resampled


def test_execution_rejects_deviation_shape_and_blocked_sketches() -> None:
    cfg = base_cfg()
    g = np.ones((120, 200), np.uint8)
    g[[0, -1], :] = 2
    g[:, [0, -1]] = 2
    g[36:84, 95:105] = 2  # detour possible inside the planner crop, but far from the sketch
    cm = build_costmap(g, 0.05, cfg["robot"], 4.0)
    kp = np.array([[20.0, 60.0], [180.0, 60.0]])
    with pytest.raises(Rejection) as err:
        execute_sketch(cm, kp, densify(kp, 1.0), 0.0, {**cfg["execution"], "shape_tolerance_deg": 360.0})
    assert err.value.reason == "deviation"
    open_cm = build_costmap(np.pad(np.ones((100, 180), np.uint8), 10, constant_values=2), 0.05, cfg["robot"], 4.0)
    with pytest.raises(Rejection) as err:
        execute_sketch(open_cm, kp, densify(kp, 1.0), 90.0, cfg["execution"])  # a straight line is not an L
    assert err.value.reason == "shape"
    g[:, 95:105] = 2
    with pytest.raises(Rejection) as err:
        execute_sketch(build_costmap(g, 0.05, cfg["robot"], 4.0), kp, kp, 0.0, cfg["execution"])
    assert err.value.reason == "no_path"


def test_draw_curve_is_one_thin_8_connected_component() -> None:
    t = np.linspace(0, np.pi, 400)
    pts = np.stack([30 + 20 * np.cos(t), 30 + 20 * np.sin(t)], axis=1)
    img = draw_curve(pts, 64)
    from scipy import ndimage

    assert ndimage.label(img, structure=np.ones((3, 3)))[1] == 1
    nbrs = ndimage.convolve(img.astype(int), np.ones((3, 3), int), mode="constant") - 1
    assert (nbrs[img] <= 2).all()  # one pixel wide: no pixel has more than two neighbours
    assert img[30, 50] and img[30, 10]


@pytest.mark.parametrize("heading_deg", [0, 37, 90, 180, 233, -90])
def test_robot_frame_puts_the_robot_at_its_pixel_heading_up(heading_deg: float) -> None:
    frame = RobotFrame.for_size(64)
    assert frame.robot_px == (32.0, 48.0)
    a = np.deg2rad(heading_deg)
    robot = np.array([100.0, 80.0])
    ahead = robot + 10 * np.array([np.cos(a), np.sin(a)])
    left_in_image = robot + 5 * np.array([np.sin(a), -np.cos(a)])  # 90 degrees counter-clockwise on screen
    pose = frame.place(robot, path_heading(np.stack([robot, ahead])))
    np.testing.assert_allclose(pose.to_window(robot), [32, 48], atol=1e-9)
    np.testing.assert_allclose(pose.to_window(ahead), [32, 38], atol=1e-9)  # straight up the image
    np.testing.assert_allclose(pose.to_window(left_in_image), [27, 48], atol=1e-9)  # a rotation, not a mirror
    pts = np.random.default_rng(0).uniform(0, 200, (20, 2))
    np.testing.assert_allclose(pose.to_map(pose.to_window(pts)), pts, atol=1e-9)


def test_robot_frame_rotation_keeps_thin_walls_and_unknown() -> None:
    """A one-cell wall at every angle stays an unbroken wall; off-map and unknown cells stay unknown."""
    frame = RobotFrame.for_size(64)
    from scipy import ndimage

    for deg in range(0, 180, 7):
        g = np.ones((200, 200), np.uint8)
        g[:, 120] = 2  # a thin wall along the rows, 20 cells east of the robot
        g[:, :60] = 0  # unknown strip far west
        pose = frame.place(np.array([100.0, 100.0]), np.deg2rad(deg))
        occ = pose.occupancy(g)
        seen = pose.to_window(np.stack([np.full(400, 120.0), np.linspace(-100, 300, 400)], axis=1))
        inside = ((seen >= 0) & (seen <= 63)).all(axis=1)
        cells = np.rint(seen[inside]).astype(int)
        assert (occ[cells[:, 1], cells[:, 0]] == 2).all(), deg  # every wall point lands on an obstacle pixel
        walls = ndimage.label(occ == 2, structure=np.ones((3, 3)))[1]
        assert walls == (1 if inside.any() else 0), deg  # never broken into pieces
        # Free space is never invented: every free window pixel maps onto free map cells.
        fr = np.argwhere(occ == 1)[:, ::-1].astype(float)
        back = np.rint(pose.to_map(fr)).astype(int)
        assert (g[back[:, 1], back[:, 0]] == 1).all()
    far = frame.place(np.array([5.0, 5.0]), 0.0).occupancy(np.ones((10, 10), np.uint8))
    assert (far == 0).sum() > 0.9 * far.size  # outside the map is unknown


def test_yaw_and_pixel_heading_round_trip() -> None:
    for yaw in (-2.0, 0.0, 0.5, 3.0):
        assert yaw_from_heading(heading_from_yaw(yaw)) == pytest.approx(yaw)
    # Rows grow downwards: a ROS yaw of +90 degrees (north) points up the map image (row decreasing).
    assert np.sin(heading_from_yaw(np.pi / 2)) == pytest.approx(-1.0)


def test_state_indices_respect_spacing_and_remaining_length() -> None:
    idx = state_indices(n_points=201, step_px=0.5, spacing_px=10, min_remaining_px=20)
    assert idx[0] == 0 and np.all(np.diff(idx) == 20) and (200 - idx[-1]) * 0.5 >= 20


def test_instance_invariants_on_a_hand_made_room() -> None:
    cfg = base_cfg()
    ctx = prepare_map("room", room(), 0.05, cfg)
    n = 0
    for shape in ("L", "U"):
        for k in range(3):
            r = generate_scenario(ctx, shape, k, cfg)
            assert r.instances, dict(r.rejections)
            for inst in r.instances:
                assert instance_problems(inst.occupancy, inst.start, inst.goal, inst.path, inst.waypoints) == []
                n += 1
            first = r.instances[0].waypoints
            assert abs(abs(total_turn_deg(first, 3)) - SHAPES[shape]) <= cfg["execution"]["shape_tolerance_deg"] + 5
    assert n > 100


def test_scenario_is_a_pure_function_of_seed_map_shape_index() -> None:
    cfg = base_cfg()
    ctx = prepare_map("room", room(), 0.05, cfg)
    a = generate_scenario(ctx, "U", 4, cfg)
    b = generate_scenario(ctx, "U", 4, cfg)
    assert a.scenario_id == "room/U004"
    assert len(a.instances) == len(b.instances)
    for x, y in zip(a.instances, b.instances):
        assert np.array_equal(x.path, y.path) and np.array_equal(x.waypoints, y.waypoints)
    other = generate_scenario(ctx, "U", 4, {**cfg, "seed": 99})
    assert not np.array_equal(other.instances[0].waypoints, a.instances[0].waypoints)
    r1, r2 = scenario_rng(0, "m", "L", 1).random(3), scenario_rng(0, "m", "L", 2).random(3)
    assert not np.allclose(r1, r2)


def test_map_without_room_for_a_goal_names_the_numbers() -> None:
    cfg = base_cfg()
    g = np.full((60, 60), 2, np.uint8)
    g[20:40, 20:40] = 1  # 1 m square: at most 0.5 m clearance, goal needs 0.655 m
    with pytest.raises(NoFreeAreaError, match=r"0\.66 m clearance.*most open cell has 0\.50 m"):
        prepare_map("tiny", g, 0.05, cfg)


def test_robot_instance_pads_outside_the_map_with_unknown_and_skips_paths_leaving_the_window() -> None:
    g = np.ones((40, 40), np.uint8)
    path = np.stack([np.linspace(5, 30, 60), np.full(60, 20.0)], axis=1)
    frame = RobotFrame.for_size(64)
    inst = robot_instance(g, path, frame, 3, 2, 16)
    assert inst is not None
    assert (inst.occupancy == 0).any() and (inst.occupancy == 1).any()
    assert instance_problems(inst.occupancy, inst.start, inst.goal, inst.path, inst.waypoints) == []
    np.testing.assert_allclose(inst.waypoints[0], [32, 48], atol=1e-5)
    np.testing.assert_allclose(inst.waypoints[-1], [32, 48 - 25], atol=1e-4)  # 25 px straight ahead
    assert inst.pose == pytest.approx((5.0, 20.0, 0.0))  # pixel pose without a to_world
    long = np.stack([np.linspace(0, 60, 120), np.full(120, 20.0)], axis=1)  # 60 px ahead > 48 - margin
    assert robot_instance(np.ones((80, 80), np.uint8), long, frame, 3, 2, 16) is None
