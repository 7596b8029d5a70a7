"""Consistent replanning: the search decoder's prior toward the previous plan (it keeps a turn between two equally
likely ones, abandons a blocked one, leaves a plan without one as it was), the planner's ``replan_prior`` setting,
and the previous plan passed by every caller of the one planner: the node, the Nav2 action, the desk simulator's
robot and the closed-loop drive."""

from __future__ import annotations

import math
from pathlib import Path
from types import SimpleNamespace as NS

import numpy as np
import pytest

from spade.closedloop.simulate import ClosedLoopSettings, drive
from spade.deploy.plan_result import PlannerConfigError
from spade.deploy.student_planner import DEFAULT_REPLAN_KEEP, DEFAULT_REPLAN_PRIOR, Planner
from spade.maps import FREE, OCCUPIED, OccupancyMap
from spade.metrics.decoding import PathDecoder
from spade.metrics.synthetic import rasterise_polyline
from spade.ros.convert import yaw_to_quaternion
from spade.ros.core import CoreSettings, PlannerCore
from factories import FRAME, ROBOT_DATA, fresh_checkpoint

H = 64
START = np.array([32.0, 54.0])
GOAL = np.array([32.0, 10.0])
LEFT = np.array([[32.0, 54.0], [20.0, 44.0], [20.0, 20.0], [32.0, 10.0]])  # round a pillar on the left ...
RIGHT = np.array([[64.0 - x, y] for x, y in LEFT])                          # ... or, mirrored, on the right


def two_ways(tilt: float) -> np.ndarray:
    """Both ways equally likely (p 0.5) but for ``tilt``: the left one p + tilt, the right one p - tilt."""
    prob = np.full((H, H), 0.01)
    prob[rasterise_polyline(LEFT, (H, H), 3)] = 0.5 + tilt
    prob[rasterise_polyline(RIGHT, (H, H), 3)] = 0.5 - tilt
    return prob.astype(np.float32)


def side(points: np.ndarray) -> str:
    return "left" if float(np.mean(points[:, 0])) < 32.0 else "right"


def pillar_grid() -> np.ndarray:
    grid = np.ones((H, H), np.uint8)
    grid[26:38, 29:36] = 2  # the pillar between the ways
    return grid


# ------------------------------------------------------------------------------------------------ the decoder
def test_without_a_prior_the_turn_flips_under_a_small_perturbation_and_with_one_it_is_kept() -> None:
    grid = pillar_grid()
    plain = PathDecoder(force_endpoints=True)
    assert side(plain(two_ways(0.02), grid, START, GOAL, 0.1).points) == "left"
    assert side(plain(two_ways(-0.02), grid, START, GOAL, 0.1).points) == "right"  # today: the turn flips
    decoder = PathDecoder(force_endpoints=True, prior_weight=DEFAULT_REPLAN_PRIOR)
    for previous in (LEFT, RIGHT):
        for tilt in (0.02, -0.02, 0.1, -0.1):
            found = decoder(two_ways(tilt), grid, START, GOAL, 0.1, prior=previous)
            assert found.ok and found.prior == "used"
            assert side(found.points) == side(previous), (side(previous), tilt)


def test_a_blocked_previous_plan_is_abandoned_and_one_the_network_does_not_see_is_left() -> None:
    grid = pillar_grid()
    grid[30, 14:29] = 2  # a wall across the left way (the map changed under the previous plan)
    decoder = PathDecoder(force_endpoints=True, prior_weight=DEFAULT_REPLAN_PRIOR)
    found = decoder(two_ways(0.1), grid, START, GOAL, 0.1, prior=LEFT)
    assert found.ok and found.prior == "blocked" and side(found.points) == "right"
    fresh = PathDecoder(force_endpoints=True)(two_ways(0.1), grid, START, GOAL, 0.1)
    np.testing.assert_array_equal(found.points, fresh.points)  # decided afresh, exactly as without a prior
    # the network now sees only the right way (the left one at the background's p 0.01): the prior is bounded
    prob = two_ways(0.0)
    prob[rasterise_polyline(LEFT, (H, H), 3)] = 0.01
    prob[rasterise_polyline(RIGHT, (H, H), 3)] = 0.9
    found = decoder(prob, pillar_grid(), START, GOAL, 0.1, prior=LEFT)
    assert found.prior == "used" and side(found.points) == "right"


def test_no_previous_plan_or_a_zero_weight_decodes_exactly_as_before() -> None:
    grid, prob = pillar_grid(), two_ways(0.02)
    before = PathDecoder(force_endpoints=True)(prob, grid, START, GOAL, 0.1)
    for decoder, prior in ((PathDecoder(force_endpoints=True, prior_weight=0.9), None),
                           (PathDecoder(force_endpoints=True, prior_weight=0.0), RIGHT)):
        found = decoder(prob, grid, START, GOAL, 0.1, prior=prior)
        assert found.prior is None
        np.testing.assert_array_equal(found.points, before.points)
    outside = PathDecoder(force_endpoints=True, prior_weight=0.8)(prob, grid, START, GOAL, 0.1, prior=RIGHT + 200)
    assert outside.prior == "outside"
    np.testing.assert_array_equal(outside.points, before.points)
    with pytest.raises(ValueError, match=r"prior_weight must lie in \[0, 1\)"):
        PathDecoder(prior_weight=1.0)


def test_keeping_returns_the_previous_plan_itself_until_a_fresh_path_is_clearly_cheaper() -> None:
    """keep_ratio: the previous plan, joined from the robot, exactly (no drift inside the band), while the fresh path
    is not cheaper by more than the ratio; replaced when the network turns against it or the map blocks it."""
    grid = pillar_grid()
    decoder = PathDecoder(force_endpoints=True, keep_ratio=0.3)
    robot = START + np.array([1.0, 0.0])  # the follower is a pixel off its plan
    for tilt in (0.02, -0.02, 0.1):  # the left way at most 1.12x the fresh path's plain cost
        found = decoder(two_ways(tilt), grid, robot, GOAL, 0.1, prior=LEFT)
        assert found.ok and found.prior == "kept" and side(found.points) == "left"
        np.testing.assert_allclose(found.points[0], robot) and np.testing.assert_allclose(found.points[-1], GOAL)
        assert np.max(np.min(np.linalg.norm(found.points[:, None] - LEFT[None], axis=2), axis=1)) < 12
    # the network turned against it (p 0.4 against 0.6: 1.7x the plain cost): kept under a ratio of 1, not of 0.3
    assert decoder(two_ways(-0.1), grid, robot, GOAL, 0.1, prior=LEFT).prior == "used"
    assert PathDecoder(force_endpoints=True, keep_ratio=1.0)(two_ways(-0.1), grid, robot, GOAL, 0.1,
                                                             prior=LEFT).prior == "kept"
    prob = two_ways(0.0)  # the network now sees only the right way: far cheaper, so the plan is replaced
    prob[rasterise_polyline(LEFT, (H, H), 3)] = 0.01
    prob[rasterise_polyline(RIGHT, (H, H), 3)] = 0.9
    found = decoder(prob, grid, robot, GOAL, 0.1, prior=LEFT)
    assert found.prior == "used" and side(found.points) == "right"
    blocked = pillar_grid()
    blocked[30, 14:29] = 2
    assert decoder(two_ways(0.1), blocked, robot, GOAL, 0.1, prior=LEFT).prior == "blocked"
    elsewhere = decoder(two_ways(0.1), grid, robot, GOAL + np.array([0.0, 6.0]), 0.1, prior=LEFT)
    assert elsewhere.prior == "used"  # the previous plan ends at another goal: never kept
    with pytest.raises(ValueError, match="keep_ratio must be >= 0"):
        PathDecoder(keep_ratio=-0.1)


# ------------------------------------------------------------------------------------------------ the planner
class TwoWays:
    """A stand-in network that sees two ways round to the goal, a detour to the robot's left and one to its right
    (a pillar's two sides, both demonstrated), and favours each in turn by a little: the noise of a network
    between two equally likely turns, which made every replan pick afresh."""

    info: dict = {}

    def __init__(self, tilt: float = 0.1) -> None:
        self.tilt, self.calls = tilt, 0

    def logits(self, states: np.ndarray) -> np.ndarray:
        from scipy import ndimage

        out = np.full((len(states), 1, *states.shape[2:]), -10.0, dtype=np.float32)
        for i, state in enumerate(states):
            (r0, c0), (r1, c1) = (np.array(ndimage.center_of_mass(state[k])) for k in (1, 2))
            s, g = np.array([c0, r0]), np.array([c1, r1])
            d = (g - s) / max(float(np.linalg.norm(g - s)), 1e-9)
            normal = np.array([-d[1], d[0]])
            favour = 1.0 if self.calls % 2 == 0 else -1.0
            self.calls += 1
            for sign in (1.0, -1.0):
                way = np.stack([s, s + 0.3 * (g - s) + 8 * sign * normal, s + 0.7 * (g - s) + 8 * sign * normal, g])
                p = 0.5 + self.tilt * sign * favour
                out[i, 0][rasterise_polyline(way, state.shape[1:], 3)] = math.log(p / (1 - p))
        return out


def two_ways_planner(path: Path, **options) -> Planner:  # noqa: ANN003
    """The planner on the stand-in network; keeping the plan off unless asked (the prior's own tests)."""
    options.setdefault("replan_keep", None)
    planner = Planner(fresh_checkpoint(path, ROBOT_DATA), **options)
    planner.backend = TwoWays()
    return planner


def room() -> OccupancyMap:
    """10 m x 10 m at 0.1 m/px, walls around, origin (0, 0)."""
    grid = np.full((100, 100), FREE, np.uint8)
    grid[0, :] = grid[-1, :] = grid[:, 0] = grid[:, -1] = OCCUPIED
    return OccupancyMap(grid, 0.1, (0.0, 0.0, 0.0), "room")


POSE, TARGET = np.array([2.0, 5.0, 0.0]), np.array([4.5, 5.0])  # the robot faces the goal 2.5 m ahead


def lateral(waypoints: np.ndarray) -> str:
    """Which side of the robot -> goal line a plan (map metres) goes round (the map's +y: the robot's left)."""
    return "left" if float(np.mean(waypoints[:, 1])) > POSE[1] else "right"


def test_replan_prior_is_a_deploy_setting_that_round_trips(tmp_path: Path) -> None:
    from omegaconf import OmegaConf

    from spade.experiments.closed_loop_evaluation import predictors
    from spade.ros.launch import build_planner
    from spade.utils.config import compose_config

    ckpt = fresh_checkpoint(tmp_path / "student.ckpt", ROBOT_DATA)
    assert Planner(ckpt).replan_prior == DEFAULT_REPLAN_PRIOR
    assert Planner(ckpt, replan_prior=0.5).replan_prior == 0.5 and Planner(ckpt, replan_prior=0).replan_prior == 0
    for bad in (-1.0, 1.0, "high", True, float("nan")):
        with pytest.raises(PlannerConfigError, match=r"replan_prior=.*: a share in \[0, 1\), e\.g\. replan_prior="):
            Planner(ckpt, replan_prior=bad)
    ros = compose_config("ros", [f"model_path={ckpt}"])
    assert ros.planner.replan_prior == DEFAULT_REPLAN_PRIOR  # the node's (and the simulator's node's) default
    assert build_planner(OmegaConf.merge(ros, {"planner": {"replan_prior": 0.0}})).replan_prior == 0.0  # off
    assert build_planner(ros).replan_prior == DEFAULT_REPLAN_PRIOR
    assert compose_config("plan", ["map=x.yaml", "start=[0,0,0]", "goal=[1,1]"]).planner.replan_prior == \
        DEFAULT_REPLAN_PRIOR
    assert predictors(ckpt, [], [], {"replan_prior": 0.3})["model"].replan_prior == 0.3  # drive.planner.*
    assert Planner(ckpt).decoder.keep_ratio == DEFAULT_REPLAN_KEEP == ros.planner.replan_keep  # the measured default
    assert Planner(ckpt, replan_keep=None).decoder.keep_ratio is None  # off
    assert build_planner(OmegaConf.merge(ros, {"planner": {"replan_keep": 0.2}})).decoder.keep_ratio == 0.2
    assert predictors(ckpt, [], [], {"replan_keep": 0.5})["model"].decoder.keep_ratio == 0.5
    for bad in (-0.1, "some", True, float("inf")):
        with pytest.raises(PlannerConfigError, match=r"replan_keep=.*: a ratio >= 0, e\.g\. replan_keep=0\.2"):
            Planner(ckpt, replan_keep=bad)


def test_the_planner_keeps_its_turn_across_replans_and_decides_afresh_with_the_prior_off(tmp_path: Path) -> None:
    m = room()
    for weight in (DEFAULT_REPLAN_PRIOR, 0.0):
        planner = two_ways_planner(tmp_path / f"w{weight}.ckpt", replan_prior=weight)
        sides, previous = [], None
        for _ in range(4):
            result = planner.plan(m, POSE, TARGET, previous=previous)
            assert result.success and result.prior == (None if previous is None or weight == 0 else "used")
            sides.append(lateral(result.waypoints))
            previous = result.waypoints
        first, other = sides[0], {"left": "right", "right": "left"}[sides[0]]
        assert sides == ([first] * 4 if weight > 0 else [first, other] * 2)  # off: the network's favourite each time


def test_a_planner_that_keeps_its_plan_returns_it_while_the_network_wavers(tmp_path: Path) -> None:
    m = room()
    # the stand-in favours each way in turn by p 0.6 against 0.4: the other way costs 1.7x as much on the plain cost
    planner = two_ways_planner(tmp_path / "keep.ckpt", replan_prior=0.0, replan_keep=1.0)
    first = planner.plan(m, POSE, TARGET)
    previous, sides = first.waypoints, [lateral(first.waypoints)]
    for _ in range(3):
        result = planner.plan(m, POSE, TARGET, previous=previous)
        assert result.success and result.prior == "kept"
        sides.append(lateral(result.waypoints))
        previous = result.waypoints
    assert len(set(sides)) == 1  # the prior off, the wavering network still never flips the kept plan


# ------------------------------------------------------------------------------------------------ every caller
class Recording:
    """The one planner, wrapped to record the previous plan each caller passes."""

    def __init__(self, planner: Planner) -> None:
        self.planner, self.resolution, self.previous = planner, planner.resolution, []

    def plan(self, m, pose, goal, previous=None):  # noqa: ANN001, ANN201
        self.previous.append(previous)
        return self.planner.plan(m, pose, goal, previous=previous)

    def plan_batch(self, maps, poses, goals, previous=None):  # noqa: ANN001, ANN201
        self.previous.extend(previous if previous is not None else [None] * len(poses))
        return self.planner.plan_batch(maps, poses, goals, previous)


def grid_msg(m: OccupancyMap) -> NS:
    pose = NS(position=NS(x=0.0, y=0.0, z=0.0), orientation=NS(x=0.0, y=0.0, z=0.0, w=1.0))
    info = NS(map_load_time=NS(sec=0, nanosec=0), resolution=m.resolution, width=m.width, height=m.height, origin=pose)
    data = np.where(m.grid[::-1] == OCCUPIED, 100, 0).reshape(-1).tolist()  # the message's first row: the bottom
    return NS(header=NS(stamp=NS(sec=1, nanosec=0), frame_id="map"), info=info, data=data)


def pose_msg(x: float, y: float, yaw: float) -> NS:
    q = yaw_to_quaternion(yaw)
    pose = NS(position=NS(x=x, y=y, z=0.0), orientation=NS(x=q[0], y=q[1], z=q[2], w=q[3]))
    return NS(header=NS(stamp=NS(sec=1, nanosec=0), frame_id="map"), pose=pose)


def test_the_node_replans_from_its_previous_plan_and_a_new_goal_plans_afresh(tmp_path: Path) -> None:
    planner = Recording(two_ways_planner(tmp_path / "student.ckpt"))
    core = PlannerCore(planner, CoreSettings(min_replan_interval_s=0.0))
    core.handle_map(grid_msg(room()))
    core.handle_pose(pose_msg(*POSE))
    first = core.handle_goal(pose_msg(*TARGET, 0.0))
    events = [first] + [core.handle_map(grid_msg(room())) for _ in range(3)]  # a map update replans (same pose)
    assert planner.previous[0] is None
    for before, after, previous in zip(events[:-1], events[1:], planner.previous[1:]):
        np.testing.assert_array_equal(previous, before.result.waypoints)
        assert after.result.prior == "used"
    assert len({lateral(e.result.waypoints) for e in events}) == 1  # the network's favourite flips each time
    core.handle_goal(pose_msg(4.5, 5.5, 0.0))
    assert planner.previous[-1] is None  # a new goal: no previous plan


def test_the_nav2_action_replans_the_same_goal_from_its_last_plan(tmp_path: Path) -> None:
    pytest.importorskip("cyclonedds")
    from spade.ros import messages as M
    from spade.ros.action import ActionSettings, GoalLogic
    from spade.ros.action_types import STATUS

    planner = Recording(two_ways_planner(tmp_path / "student.ckpt"))
    core = PlannerCore(planner, CoreSettings())
    core.handle_map(grid_msg(room()))
    paths: list = []
    logic = GoalLogic(core, ActionSettings(enabled=True), clock=lambda: 0.0, now_ns=lambda: 10**9,
                      on_path=lambda path, event: paths.append(event.result))
    T = logic.T

    def ask(n: int, goal: tuple[float, float, float]) -> None:
        g = T.Goal(M.pose_stamped(goal, "map", 0), M.pose_stamped(tuple(POSE), "map", 0), "", True)
        assert logic.send_goal(T.SendGoalRequest(5, n, T.UUID([n] * 16), g)).accepted
        logic.step()
        reply = logic.get_result(T.GetResultRequest(5, 100 + n, T.UUID([n] * 16)))
        assert reply.status == STATUS.SUCCEEDED

    for n in range(1, 4):  # Nav2's behaviour tree asks again for the same goal about once a second
        ask(n, (*TARGET, 0.0))
    assert len(paths) == 3 and planner.previous[0] is None
    for before, previous in zip(paths[:-1], planner.previous[1:3]):
        np.testing.assert_array_equal(previous, before.waypoints)
    assert [r.prior for r in paths] == [None, "used", "used"]
    assert len({lateral(r.waypoints) for r in paths}) == 1
    ask(4, (4.5, 5.5, 0.0))
    assert planner.previous[-1] is None  # another goal: afresh


def test_the_desk_simulators_robot_and_the_closed_loop_drive_replan_from_their_previous_plans(tmp_path: Path
                                                                                            ) -> None:
    from spade.ros.sim import SimRobot, SimSettings

    m = room()
    # the simulator: its robot follows the node's plans and sends its pose back (python -m spade.ros sim starts
    # the node, PlannerCore, with the model's planner)
    planner = Recording(two_ways_planner(tmp_path / "sim.ckpt"))
    core = PlannerCore(planner, CoreSettings(min_replan_interval_s=0.0, replan_every_m=0.3))
    core.handle_map(grid_msg(m))
    core.handle_pose(pose_msg(*POSE))
    robot = SimRobot(POSE.copy(), m, SimSettings())
    events = [core.handle_goal(pose_msg(*TARGET, 0.0))]
    robot.plan = events[0].result.waypoints
    for _ in range(60):
        event = core.handle_pose(pose_msg(*robot.step()))
        if event is not None and event.success:
            events.append(event)
            robot.plan = event.result.waypoints
    assert len(events) >= 3
    for before, previous in zip(events[:-1], planner.previous[1:]):
        np.testing.assert_array_equal(previous, before.result.waypoints)
    assert all(e.result.prior == "used" for e in events[1:])
    # the closed loop: each episode's previous plan, in the batch
    from factories import arc_l, scenario

    planner = Recording(two_ways_planner(tmp_path / "drive.ckpt", far_goal="clip"))
    sc = scenario(m, arc_l(np.array([2.0, 2.0]), 1.5, 0.5, 1.5))
    (episode,) = drive(planner, [sc], ClosedLoopSettings())
    assert len(episode.plans) >= 3 and planner.previous[0] is None
    for before, previous in zip(episode.plans[:-1], planner.previous[1:]):
        np.testing.assert_array_equal(previous, before.waypoints)
    assert [p.prior for p in episode.plans[1:]] == ["used"] * (len(episode.plans) - 1)


def test_the_node_and_the_closed_loop_drive_keep_the_plan_itself_with_replan_keep(tmp_path: Path) -> None:
    """replan_keep is the decoder's, so every caller of the planner gets it: the node's replans on a map update
    return the first plan (joined from the robot) while the stand-in network wavers; the drive's replans keep too."""
    planner = Recording(two_ways_planner(tmp_path / "node.ckpt", replan_prior=0.0, replan_keep=1.0))
    core = PlannerCore(planner, CoreSettings(min_replan_interval_s=0.0))
    core.handle_map(grid_msg(room()))
    core.handle_pose(pose_msg(*POSE))
    events = [core.handle_goal(pose_msg(*TARGET, 0.0))] + [core.handle_map(grid_msg(room())) for _ in range(3)]
    assert [e.result.prior for e in events] == [None, "kept", "kept", "kept"]
    for event in events[1:]:
        np.testing.assert_allclose(event.result.waypoints, events[0].result.waypoints, atol=0.06)
    from factories import arc_l, scenario

    planner = Recording(two_ways_planner(tmp_path / "drive.ckpt", far_goal="clip", replan_prior=0.0,
                                         replan_keep=1.0))
    (episode,) = drive(planner, [scenario(room(), arc_l(np.array([2.0, 2.0]), 1.5, 0.5, 1.5))], ClosedLoopSettings())
    assert "kept" in {p.prior for p in episode.plans[1:]}


def test_the_replanning_page_compares_each_prior_with_off_on_the_same_students(tmp_path) -> None:
    """spade.perf.replanning_page: a paired t-test over the students, Holm over the page, the targets said met or
    missed, the followed demonstration beside; written from the drive records alone."""
    import json

    from spade.perf.replanning_page import load_drive_records, replanning_page

    for i, student in enumerate(("a", "b", "c")):
        for prior, keep, ape, switches in ((0.0, None, 15.0 + i, 1.0 + 0.1 * i), (0.9, None, 6.0 + 0.9 * i, 0.2 + 0.01 * i),
                                           (0.9, 0.5, 6.5 + i, 0.1)):
            metrics = {"closed_loop/ape_cm": ape, "closed_loop/mode_switches": switches,
                       "closed_loop/commit_rate": 0.8, "closed_loop/success_rate": 1.0,
                       "closed_loop/followed/ape_cm": 4.5, "closed_loop/followed/mode_switches": 0.1,
                       "closed_loop/followed/commit_rate": 1.0, "closed_loop/followed/success_rate": 1.0}
            (tmp_path / f"{student}_{prior}_{keep}.json").write_text(json.dumps({
                "run": student, "condition": "clean", "replan_prior": prior, "metrics": metrics, "scenarios": 10,
                **({} if keep is None else {"replan_keep": keep}),  # records before the keep lever have none
                "command": "python -m spade.perf.replanning --ckpt x", "commit": "abc", "seconds": 6.0}))
    (tmp_path / "summary.json").write_text("[]")  # not a drive record
    records = load_drive_records(tmp_path)
    assert len(records) == 9
    page = replanning_page(records)
    assert page.startswith("# Replanning") and "(Holm's correction over the page's 3 tests)" in page  # keep's switches: no spread
    verdict = [line for line in page.splitlines() if line.startswith("- **clean**")][0]
    assert "the best setting (prior 0.9) against off" in verdict
    assert "closed-loop APE (cm) 16.00 → 6.90" in verdict and "Every target met." in verdict
    assert "| clean | prior 0.9 | 6.90 ± 0.90 |" in page and "| clean | prior 0.9 + keep 0.5 | 7.50 ± 1.00 |" in page
    assert "| clean | off | 16.00 ± 1.00 |" in page
    for student, prior in (("a", 0.0), ("b", 0.0), ("a", 0.9), ("b", 0.9)):  # another test set: its own condition
        (tmp_path / f"{student}_{prior}_real.json").write_text(json.dumps({
            "run": student, "condition": "clean", "data": "realmap_L", "replan_prior": prior, "scenarios": 5,
            "metrics": {"closed_loop/ape_cm": 20.0 - 5 * prior, "closed_loop/mode_switches": 1.0}, "seconds": 1.0}))
    page = replanning_page(load_drive_records(tmp_path))
    assert "| clean, realmap_L | off | 20.00 ± 0.00 |" in page and "| clean | off | 16.00 ± 1.00 |" in page
    real = next(line for line in page.splitlines() if line.startswith("- **clean, realmap_L**"))
    assert real.endswith("No targets on this test set: its direction only.") and "20.00 → 15.50" in real and "| clean | the demonstration, followed | 4.50 |" in page
    assert page.index("- **clean**") < page.index("| condition |")  # the verdict before the table
