"""spade.planner in the robot frame: the training window exactly, robots at several headings on a real map,
failure results, batch form, the three kinds of model file, and a round trip with a briefly trained student."""

from __future__ import annotations

import math
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
import torch
from omegaconf import OmegaConf
from scipy import ndimage
from skimage.draw import line

from spade.annotation.scenarios import generate_scenario, prepare_map
from spade.data.rasterize import render, robot_instance, state_indices
from spade.maps import FREE, OCCUPIED, OccupancyMap, generate_map, load_ros_map
from spade.maps.frame import RobotFrame, heading_from_yaw, path_heading, yaw_from_heading
from spade.models.builders import build_model
from spade.planner import Planner, PlannerConfigError, PlanResult
from spade.utils.config import compose_config
from factories import LineOracle
from factories import FRAME, RES, ROBOT_DATA, SIZE, facing, fresh_checkpoint, open_segment

REAL_MAP = ("aws-robomaker-small-warehouse-world", "small_warehouse_002.yaml")


# ------------------------------------------------------------------------------------------------ helpers


class Silent:
    """A stand-in network that predicts no path at all."""

    def logits(self, states: np.ndarray) -> np.ndarray:
        return np.full((len(states), 1, *states.shape[2:]), -10.0, dtype=np.float32)


@pytest.fixture(scope="module")
def ckpt(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return fresh_checkpoint(tmp_path_factory.mktemp("planner") / "student.ckpt", ROBOT_DATA)


@pytest.fixture(scope="module")
def warehouse() -> OccupancyMap:
    return generate_map("warehouse", 1)  # 0.05 m/px: the planner resamples it to the student's 0.1


@pytest.fixture(scope="module")
def real_map(maps_dir: Path) -> OccupancyMap:
    return load_ros_map(maps_dir.joinpath(*REAL_MAP))


def oracle_planner(ckpt: Path, **kwargs) -> Planner:
    planner = Planner(ckpt, **kwargs)
    planner.backend = LineOracle()
    return planner


def free_in(m: OccupancyMap, xy: np.ndarray) -> np.ndarray:
    """Whether each point (metres) lies on a FREE cell of ``m``."""
    col, row = np.rint(m.world_to_pixel(xy)).astype(int).T
    return m.grid[row, col] == FREE


def assert_good_plan(result: PlanResult, m: OccupancyMap, pose: np.ndarray, goal: np.ndarray, atol: float) -> None:
    """Waypoints from the robot to the goal, in metres, every one on a free cell (of the map and of the map at
    the student's resolution, which the planner saw)."""
    assert result.success, (result.code, result.reason)
    assert result.waypoints.ndim == 2 and result.waypoints.shape[1] == 2 and len(result.waypoints) >= 2
    np.testing.assert_allclose(result.waypoints[0], pose[:2], atol=atol)
    np.testing.assert_allclose(result.waypoints[-1], goal, atol=atol)
    assert free_in(m, result.waypoints).all(), "a waypoint off the free space of the map"
    assert free_in(m.resampled(RES), result.waypoints).all(), "a waypoint off the free space the student saw"
    np.testing.assert_array_equal(result.pose, pose)


# ------------------------------------------------------------------------------------------------ the window
def test_the_query_window_is_the_training_window(ckpt: Path, warehouse: OccupancyMap) -> None:
    """A planner query for an annotation instance's robot pose and goal gives that instance's state exactly."""
    coarse = warehouse.resampled(RES)
    a, b = open_segment(warehouse, 2.5, seed=1)
    remaining = coarse.world_to_pixel(np.linspace(a, b, 40))
    inst = robot_instance(coarse.grid, remaining, FRAME, 0.3 / RES, 0.1 / RES, 16,
                          to_world=lambda x, y, h: (*coarse.pixel_to_world(np.array([x, y])), yaw_from_heading(h)))
    assert inst is not None
    result = oracle_planner(ckpt).plan(warehouse, inst.pose, b)
    expected = np.stack([inst.occupancy * 0.5, inst.start, inst.goal]).astype(np.float32)
    np.testing.assert_array_equal(result.state, expected)
    assert_good_plan(result, warehouse, np.asarray(inst.pose), b, atol=1e-6)
    # The window lies in the robot's frame: 1 m ahead of the robot is 10 px up the image from its pixel.
    x, y, yaw = inst.pose
    ahead = result.window.to_window(np.array([x + math.cos(yaw), y + math.sin(yaw)]))
    np.testing.assert_allclose(ahead, [FRAME.robot_px[0], FRAME.robot_px[1] - 1.0 / RES], atol=1e-6)
    left = result.window.to_window(np.array([x - math.sin(yaw), y + math.cos(yaw)]))  # 1 m to the robot's left
    np.testing.assert_allclose(left, [FRAME.robot_px[0] - 1.0 / RES, FRAME.robot_px[1]], atol=1e-6)


def test_state_built_with_the_frame_module(ckpt: Path, warehouse: OccupancyMap) -> None:
    """The same check from first principles: frame.place, pose.occupancy and render, at an arbitrary heading."""
    coarse = warehouse.resampled(RES)
    a, b = open_segment(warehouse, 2.0, seed=4)
    pose = facing(a, b, turn=0.4)  # the goal 23 degrees off the heading
    wp = FRAME.place(coarse.world_to_pixel(pose[:2]), heading_from_yaw(pose[2]))
    goal_px = wp.to_window(coarse.world_to_pixel(b))
    inst = render(wp.occupancy(coarse.grid), np.stack([np.asarray(FRAME.robot_px), goal_px]), 0.1 / RES, 2)
    result = oracle_planner(ckpt).plan(warehouse, pose, b)
    np.testing.assert_array_equal(result.state, np.stack([inst.occupancy * 0.5, inst.start, inst.goal]))
    assert result.state[1, int(FRAME.robot_px[1]), int(FRAME.robot_px[0])] == 1.0  # start disc on the robot pixel


@pytest.mark.parametrize("degrees", [0, 60, 135, 200, 290])
def test_robots_at_several_headings_on_a_real_map(ckpt: Path, real_map: OccupancyMap, degrees: int) -> None:
    """Robots facing anywhere: waypoints start at the robot, end at the goal, stay on free cells; the same goal
    behind the robot (beyond the window's reach behind it) is too far."""
    planner = oracle_planner(ckpt, num_waypoints=24)
    done = 0
    for seed in range(40):
        a, b = open_segment(real_map, 2.0, seed=seed * 7 + degrees)
        heading = math.atan2(*(b - a)[::-1])
        if abs((math.degrees(heading) - degrees + 180) % 360 - 180) > 45:  # keep robots facing about `degrees`
            continue
        pose = facing(a, b)
        result = planner.plan(real_map, pose, b)
        assert_good_plan(result, real_map, pose, b, atol=1e-6)
        assert abs(result.length_m - 2.0) < 0.1
        d = result.waypoints - a  # on the straight segment, as the oracle drew it
        u = (b - a) / 2.0
        assert np.abs(d[:, 0] * u[1] - d[:, 1] * u[0]).max() < RES
        back = planner.plan(real_map, facing(a, b, turn=math.pi), b)  # 2 m behind: the window reaches 1.2 m
        assert back.code == "goal_too_far" and "2.00 m behind the robot" in back.reason
        assert back.waypoints.shape == (0, 2)
        done += 1
        if done == 2:
            break
    assert done == 2, f"too few open segments facing {degrees} degrees"


def test_waypoints_follow_the_prediction_in_the_robot_frame(ckpt: Path, real_map: OccupancyMap) -> None:
    """A prediction drawn in window pixels comes back at the right place in the map: a detour to the robot's
    left in the window is a detour to its left in the map, whatever the heading."""
    a, b = open_segment(real_map, 1.5, seed=11, clearance_m=0.6)

    class LeftDetour:
        def logits(self, states: np.ndarray) -> np.ndarray:
            out = np.full((len(states), 1, SIZE, SIZE), -10.0, dtype=np.float32)
            for i, state in enumerate(states):
                (r0, c0), (r1, c1) = (np.rint(ndimage.center_of_mass(state[k])).astype(int) for k in (1, 2))
                mid_r, mid_c = (r0 + r1) // 2, min(c0, c1) - 4  # 0.4 m to the robot's left of the midpoint
                for (ra, ca), (rb, cb) in (((r0, c0), (mid_r, mid_c)), ((mid_r, mid_c), (r1, c1))):
                    rr, cc = line(ra, ca, rb, cb)
                    out[i, 0, rr, cc] = 10.0
            return out

    planner = Planner(ckpt, collision_check=False)
    planner.backend = LeftDetour()
    u = (b - a) / np.linalg.norm(b - a)
    left = np.array([-u[1], u[0]])  # left of the way from the robot to the goal
    for turn in (0.0, 0.3, -0.5):
        result = planner.plan(real_map, facing(a, b, turn), b)
        assert result.success, result.reason
        offsets = (result.waypoints - a) @ left
        assert offsets.max() > 0.3 and offsets.min() > -0.05  # the whole detour on the left


# ------------------------------------------------------------------------------------------------ failures
def test_a_position_without_yaw_is_refused_with_the_fix(ckpt: Path, warehouse: OccupancyMap) -> None:
    a, b = open_segment(warehouse, 2.0)
    with pytest.raises(ValueError, match=r"pose \(x, y, yaw\).*start=X,Y,YAW"):
        oracle_planner(ckpt).plan(warehouse, a, b)
    with pytest.raises(ValueError, match="robot pose"):
        oracle_planner(ckpt).plan(warehouse, [1.0, 2.0, float("nan")], b)


@pytest.mark.parametrize(
    ("case", "code"),
    [("start_wall", "start_not_free"), ("goal_out", "goal_outside_map"), ("far", "goal_too_far"),
     ("start_unknown", "start_not_free")],
)
def test_invalid_queries_fail_with_a_reason(ckpt: Path, warehouse: OccupancyMap, case: str, code: str) -> None:
    start, goal = open_segment(warehouse, 5.0 if case == "far" else 2.0)  # far: beyond the window's 4.5 m ahead
    grid = warehouse.grid.copy()
    if case in ("start_wall", "start_unknown"):
        col, row = np.rint(warehouse.world_to_pixel(start)).astype(int)
        grid[row, col] = OCCUPIED if case == "start_wall" else 0
    m = OccupancyMap(grid, warehouse.resolution, warehouse.origin, warehouse.name)
    if case == "goal_out":
        goal = np.array([m.origin[0] - 1.0, goal[1]])
    pose = facing(start, goal)
    result = oracle_planner(ckpt).plan(m, pose, goal)
    assert not result.success and not result
    assert result.code == code and isinstance(result.reason, str) and len(result.reason) > 20
    assert result.waypoints.shape == (0, 2) and result.probability is None


def test_far_goal_clip_plans_to_a_subgoal(ckpt: Path, warehouse: OccupancyMap) -> None:
    start, goal = open_segment(warehouse, 9.0, seed=3)
    pose = facing(start, goal, turn=0.2)
    assert oracle_planner(ckpt).plan(warehouse, pose, goal).code == "goal_too_far"
    result = oracle_planner(ckpt, far_goal="clip").plan(warehouse, pose, goal)
    assert result.success and result.subgoal
    u = (goal - start) / np.linalg.norm(goal - start)
    progress = (result.waypoints[-1] - start) @ u
    assert 2.0 < progress < 9.0 and np.linalg.norm(result.goal - result.waypoints[-1]) < 1e-9
    end = result.window.to_window(result.waypoints[-1])
    assert FRAME.inside(end[None], 0.3 / RES - 1e-6)  # the sub-goal lies margin_m inside the window


def test_no_path_is_a_failure_result_with_the_probabilities(ckpt: Path, warehouse: OccupancyMap) -> None:
    """The paper's extraction finds nothing in an empty prediction: a failure result that keeps the image."""
    start, goal = open_segment(warehouse, 2.0)
    planner = Planner(ckpt, decode="skeleton")
    planner.backend = Silent()
    result = planner.plan(warehouse, facing(start, goal), goal)
    assert (result.success, result.code) == (False, "empty") and "no path" in result.reason
    assert result.waypoints.shape == (0, 2) and result.probability is not None and result.probability.max() < 0.5


def test_search_decoding_reaches_the_goal_and_flags_what_it_did_not_see(ckpt: Path, warehouse: OccupancyMap) -> None:
    """An empty prediction: the search still plans from the robot to the goal over free cells, flagged as low
    confidence (all of it through p < 0.5); fallback='shortest' swaps in the Nav2-like path, flagged."""
    start, goal = open_segment(warehouse, 2.0)
    pose = facing(start, goal, turn=0.3)
    planner = Planner(ckpt)
    planner.backend = Silent()
    result = planner.plan(warehouse, pose, goal)
    assert result.success and result.decode == "search" and result.code is None
    assert result.low_confidence and result.low_share == 1.0 and result.min_probability < 0.5 and not result.fallback
    assert_good_plan(result, warehouse, pose, goal, atol=1e-6)
    fallback = Planner(ckpt, fallback="shortest")
    fallback.backend = Silent()
    swapped = fallback.plan(warehouse, pose, goal)
    assert swapped.success and swapped.fallback and swapped.low_confidence
    assert_good_plan(swapped, warehouse, pose, goal, atol=1e-6)
    oracle = oracle_planner(ckpt, fallback="shortest").plan(warehouse, pose, goal)
    assert oracle.success and not oracle.low_confidence and not oracle.fallback and oracle.low_share < 0.1
    with pytest.raises(PlannerConfigError, match="decode"):
        Planner(ckpt, decode="threshold")
    with pytest.raises(PlannerConfigError, match="fallback"):
        Planner(ckpt, fallback="straight")


def test_a_path_away_from_the_robot_is_a_failure(ckpt: Path, warehouse: OccupancyMap) -> None:
    class Elsewhere:
        """Predicts a line from 1 m ahead of the robot to the goal: it never touches the robot."""

        def logits(self, states: np.ndarray) -> np.ndarray:
            out = np.full((len(states), 1, SIZE, SIZE), -10.0, dtype=np.float32)
            (r1, c1) = np.rint(ndimage.center_of_mass(states[0, 2])).astype(int)
            rr, cc = line(int(FRAME.robot_px[1]) - 10, int(FRAME.robot_px[0]) + 8, r1, c1)
            out[0, 0, rr, cc] = 10.0
            return out

    start, goal = open_segment(warehouse, 3.0, seed=5)
    planner = Planner(ckpt, decode="skeleton")
    planner.backend = Elsewhere()
    result = planner.plan(warehouse, facing(start, goal), goal)
    assert result.code == "start_not_reached" and "from the robot" in result.reason and result.waypoints.shape == (0, 2)
    # decoded by search, the same prediction gives a path from the robot that joins the predicted line
    searched = Planner(ckpt)
    searched.backend = Elsewhere()
    pose = facing(start, goal)
    result = searched.plan(warehouse, pose, goal)
    assert result.success and 0 < result.low_share < 0.6
    assert_good_plan(result, warehouse, pose, goal, atol=1e-6)


def test_batch_equals_single_queries_and_keeps_order(ckpt: Path, warehouse: OccupancyMap) -> None:
    planner = oracle_planner(ckpt, batch_size=2)
    pairs = [open_segment(warehouse, 2.5, seed=s) for s in range(3)]
    poses = [facing(a, b, 0.1 * i) for i, (a, b) in enumerate(pairs)] + [np.array([-50.0, -50.0, 0.0])]
    goals = [b for _, b in pairs] + [pairs[0][1]]
    batch = planner.plan_batch(warehouse, poses, goals)
    assert [r.success for r in batch] == [True, True, True, False] and batch[3].code == "start_outside_map"
    for r, p, g in zip(batch[:3], poses, goals):
        single = planner.plan(warehouse, p, g)
        np.testing.assert_array_equal(r.waypoints, single.waypoints)


# ------------------------------------------------------------------------------------------------ model files
def test_model_file_errors(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="does not exist"):
        Planner(tmp_path / "missing.ckpt")
    for name, data in (("none", None), ("axis", {"image_size": [SIZE, SIZE], "resolution_m": RES})):
        old = fresh_checkpoint(tmp_path / f"{name}.ckpt", data)  # older, axis-aligned students
        with pytest.raises(PlannerConfigError, match="axis-aligned.*[Rr]etrain"):
            Planner(old)
    torch.save({"spade": {"role": "expert", "config": {}}, "state_dict": {}}, tmp_path / "expert.ckpt")
    with pytest.raises(PlannerConfigError, match="not 'student'"):
        Planner(tmp_path / "expert.ckpt")
    wrong = fresh_checkpoint(tmp_path / "wrong.ckpt", {**ROBOT_DATA, "frame": RobotFrame.for_size(32).to_json()})
    with pytest.raises(PlannerConfigError, match="disagrees"):
        Planner(wrong)
    with pytest.raises(PlannerConfigError, match="far_goal"):
        Planner(fresh_checkpoint(tmp_path / "ok.ckpt", ROBOT_DATA), far_goal="nearest")


@pytest.mark.filterwarnings("ignore::DeprecationWarning")
def test_checkpoint_onnx_and_torchscript_plan_alike(ckpt: Path, warehouse: OccupancyMap, tmp_path: Path) -> None:
    pytest.importorskip("onnxruntime")
    from spade.deploy.export import export_student

    start, goal = open_segment(warehouse, 2.0, seed=2)
    pose = facing(start, goal, 0.3)
    reference = Planner(ckpt).plan(warehouse, pose, goal)
    for fmt in ("onnx", "torchscript"):
        out = export_student(ckpt, tmp_path / f"s.{fmt}", fmt, latency_runs=0).out_path
        planner = Planner(out)
        assert planner.backend.format == fmt and planner.frame == FRAME
        got = planner.plan(warehouse, pose, goal)
        np.testing.assert_array_equal(got.state, reference.state)
        assert np.abs(got.probability - reference.probability).max() < 1e-4


def test_public_path() -> None:
    import spade.deploy.plan_result as result
    import spade.deploy.robot_window as window
    import spade.deploy.student_planner as impl
    import spade.planner as public

    assert public.Planner is impl.Planner and public.PlanResult is result.PlanResult and PlanResult is result.PlanResult
    assert public.PlanWindow is window.PlanWindow and public.PlannerConfigError is result.PlannerConfigError


# ------------------------------------------------------------------------------------------------ trained
def annotation_queries(m: OccupancyMap, scenarios: int, per_scenario: int = 3, seed: int = 5
                       ) -> list[tuple[np.ndarray, np.ndarray]]:
    """(robot pose, goal) in metres as the annotation tool makes them: states along executed L sketches, the
    robot heading along its path."""
    cfg = compose_config("annotate", ["annotate/preset@_global_=test", f"window.size_px={SIZE}",
                                      f"window.resolution_m={RES}", f"seed={seed}"])
    cfg = OmegaConf.to_container(cfg, resolve=True)
    coarse = m.resampled(RES)
    ctx = prepare_map(m.name, coarse.grid, RES, cfg, m.origin)
    out = []
    for k in range(scenarios):
        executed = generate_scenario(ctx, "L", k, cfg).executed
        if executed is None:
            continue
        idx = state_indices(len(executed.points), executed.step_px, 0.05 / RES, 0.3 / RES)
        for i in idx[np.linspace(0, len(idx) - 1, per_scenario).round().astype(int)]:
            remaining = executed.points[i:]
            if not FRAME.inside(FRAME.place(remaining[0], path_heading(remaining)).to_window(remaining), 3.0):
                continue  # the annotation tool skips such states too
            xy = coarse.pixel_to_world(remaining[0])
            out.append((np.array([*xy, yaw_from_heading(path_heading(remaining))]),
                        coarse.pixel_to_world(remaining[-1])))
    return out


@pytest.fixture(scope="module")
def trained_student(spade_home: Path) -> str:
    """A small BC student trained briefly at scale tiny (L shape), path pixels weighted 4x in the BCE."""
    from spade.experiments.run import train
    from training_helpers import compose_row

    cfg = compose_row("t1_small_bc_L", spade_home, "logger=none", "callbacks=none", "test=false",
                      "model.bc_pos_weight=4", "trainer.max_epochs=30", "recipe.student_lr=3e-3",
                      "+trainer.limit_val_batches=0", "model.grid_size=0", "trainer.enable_progress_bar=false")
    _, objects = train(cfg)
    path = spade_home / "planner_student.ckpt"
    objects["trainer"].save_checkpoint(path)
    return str(path)


def _round_trip(ckpt: str, m: OccupancyMap, scenarios: int) -> tuple[list[PlanResult], int]:
    queries = annotation_queries(m, scenarios)
    assert len(queries) >= 6, f"too few annotation queries on {m.name}"
    results = Planner(ckpt).plan_batch(m, [p for p, _ in queries], [g for _, g in queries])
    headings = set()
    for (pose, goal), r in zip(queries, results):
        if r.success:
            assert_good_plan(r, m, pose, goal, atol=2 * RES)
            headings.add(round(math.degrees(pose[2]) / 45) % 8)
        else:
            assert r.code and r.reason and r.waypoints.shape == (0, 2)
    assert len(headings) >= 2, "the successful plans should span several headings"
    return results, len(queries)


@pytest.mark.slow  # trains a student 30 epochs; the window, frame and failures with stand-in networks: above
def test_trained_student_round_trip_on_a_procedural_map(trained_student: str) -> None:
    results, n = _round_trip(trained_student, generate_map("warehouse", 101), scenarios=6)
    codes = Counter(r.code for r in results)
    assert codes[None] >= n // 2, codes


@pytest.mark.slow
def test_trained_student_round_trip_on_a_real_map(trained_student: str, real_map: OccupancyMap) -> None:
    results, n = _round_trip(trained_student, real_map, scenarios=6)
    codes = Counter(r.code for r in results)
    assert codes[None] >= n // 2, codes  # a real map it never saw


@pytest.mark.slow  # python -m spade.plan processes
def test_plan_command_prints_waypoints_and_writes_the_picture(trained_student: str, tmp_path: Path) -> None:
    import subprocess
    import sys

    m = generate_map("warehouse", 101)
    pose, goal = annotation_queries(m, 6)[0]
    repo = Path(__file__).resolve().parents[1]
    base = [sys.executable, "-m", "spade.plan", "warehouse:101", f"model={trained_student}",
            f"hydra.run.dir={tmp_path}/run"]
    ok = subprocess.run([*base, "start=" + ",".join(map(str, pose)), f"goal={goal[0]},{goal[1]}",
                         f"out={tmp_path}/plan.png"], cwd=repo, capture_output=True, text=True, timeout=300)
    expected = Planner(trained_student).plan(m, pose, goal)
    lines = [ln for ln in ok.stdout.splitlines() if ln and not ln.startswith("#")]
    assert ok.returncode == (0 if expected.success else 1), ok.stdout + ok.stderr
    if expected.success:
        np.testing.assert_allclose(np.array([[float(v) for v in ln.split()] for ln in lines]), expected.waypoints,
                                   atol=1e-3)
    else:
        assert expected.code in ok.stdout and not lines
    assert (tmp_path / "plan.png").stat().st_size > 1000
    # A goal off the map: a failure result, exit status 1, the reason printed, the picture still written.
    bad = subprocess.run([*base, "start=" + ",".join(map(str, pose)), "goal=-100,-100", f"out={tmp_path}/bad.png"],
                         cwd=repo, capture_output=True, text=True, timeout=300)
    assert bad.returncode == 1 and "goal_outside_map" in bad.stdout, bad.stdout + bad.stderr
    assert (tmp_path / "bad.png").is_file()
    # A start without its yaw: refused, naming the fix.
    noyaw = subprocess.run([*base, f"start={pose[0]},{pose[1]}", f"goal={goal[0]},{goal[1]}"], cwd=repo,
                           capture_output=True, text=True, timeout=300)
    assert noyaw.returncode != 0 and "start=X,Y,YAW" in noyaw.stderr, noyaw.stderr[-2000:]


def test_a_plan_picture_carries_its_legend() -> None:
    """Once, ``plan.png`` had no legend. Every colour of the picture is named in a strip below it."""
    import numpy as np
    from PIL import Image

    from spade.deploy.plan_picture import LEGEND, with_legend

    out = np.asarray(with_legend(Image.new("RGB", (640, 300), (255, 255, 255))))
    assert out.shape[1] == 640 and out.shape[0] > 300
    strip = out[300:].reshape(-1, 3)
    for _, colour, _ in LEGEND:
        if colour is not None:
            assert (np.abs(strip.astype(int) - colour).sum(axis=1) < 10).any(), colour
