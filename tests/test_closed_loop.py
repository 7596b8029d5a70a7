"""Closed loop (spade.closedloop, spade.metrics.closed_loop): the follower, the node's replanning rule, the episode
figures against hand-computed values, and whole episodes on a hand-made map: success, a collision, determinism."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from spade.deploy.follower import FollowerSettings, follow_step, lookahead_point
from spade.closedloop.planners import BaselinePlanner, DemonstrationPlanner
from spade.closedloop.scenario_loading import Scenario, scenario_starts
from spade.closedloop.simulate import ClosedLoopSettings, Episode, PlanRecord, drive, replay
from spade.data.polyline import resample_polyline
from spade.deploy.plan_result import PlanResult
from spade.maps.costmap import build_costmap
from spade.maps.frame import RobotFrame
from spade.maps.occupancy import FREE, OCCUPIED, OccupancyMap
from spade.metrics.closed_loop import CLOSED_LOOP_KEYS, ClosedLoopMetrics, episode_figures, plan_mode, smoothness
from spade.ros.core import CoreSettings, replan_trigger
from factories import arc_l, scenario


def open_map(block: tuple[slice, slice] | None = None) -> OccupancyMap:
    """A 10 m x 10 m room at 0.1 m/px, walls around, origin (0, 0); optionally an obstacle block (rows, cols)."""
    grid = np.full((100, 100), FREE, np.uint8)
    grid[0, :] = grid[-1, :] = grid[:, 0] = grid[:, -1] = OCCUPIED
    if block is not None:
        grid[block] = OCCUPIED
    return OccupancyMap(grid, 0.1, (0.0, 0.0, 0.0), "room")


FRAME = RobotFrame.for_size(64)


# -- the follower ------------------------------------------------------------------------------------------------
def test_follower_drives_a_straight_plan_at_its_speed_and_stops_at_the_end() -> None:
    s = FollowerSettings()
    plan = np.array([[0.0, 0.0], [2.0, 0.0]])
    pose = np.array([0.0, 0.0, 0.0])
    for _ in range(5):
        pose = follow_step(pose, plan, s)
    np.testing.assert_allclose(pose, [5 * s.speed_mps * s.dt_s, 0.0, 0.0], atol=1e-9)
    for _ in range(200):
        pose = follow_step(pose, plan, s)
    assert np.linalg.norm(pose[:2] - plan[-1]) < 1e-6  # slows down onto the end, never past it


def test_follower_turns_on_the_spot_towards_a_plan_behind_it_and_tracks_an_arc() -> None:
    s = FollowerSettings()
    behind = follow_step(np.array([0.0, 0.0, 0.0]), np.array([[0.0, 0.0], [-2.0, 0.0]]), s)
    assert behind[:2] == pytest.approx([0.0, 0.0]) and behind[2] == pytest.approx(s.max_angular_rps * s.dt_s)
    demo = arc_l(np.array([1.0, 1.0]), 1.0, 0.9, 1.0)
    pose = np.array([1.0, 1.0, 0.0])
    errors = []
    for _ in range(200):
        pose = follow_step(pose, demo, s)
        k = np.linalg.norm(resample_polyline(demo, 2000) - pose[:2], axis=1).min()
        errors.append(k)
    assert max(errors) < 0.05  # pure pursuit cuts a 0.9 m turn by a few centimetres at most
    assert lookahead_point(np.array([1.0, 1.0]), demo, 0.3) == pytest.approx([1.3, 1.0], abs=1e-6)


def test_follower_settings_are_checked() -> None:
    with pytest.raises(ValueError, match="speed_mps must be a positive number"):
        FollowerSettings(speed_mps=0)


# -- the node's replanning rule ------------------------------------------------------------------------------------
def test_replan_trigger_is_the_nodes_rule_with_a_travelled_distance() -> None:
    plan = np.array([[0.0, 0.0], [3.0, 0.0]])
    node = CoreSettings()
    here = np.array([1.0, 0.1, 0.0])
    assert replan_trigger(node, here, plan, False, np.array([0.9, 0.0, 0.0]), 5.0) is None
    assert replan_trigger(node, np.array([1.0, 0.7, 0.0]), plan, False, here, 5.0).startswith("off the plan by 0.70")
    assert replan_trigger(node, np.array([1.0, 0.7, 0.0]), plan, False, here, 0.2) is None  # too soon
    assert replan_trigger(node, np.array([2.5, 0.0, 0.0]), plan, True, here, 5.0) == "near the sub-goal"
    every = CoreSettings(replan_every_m=0.5)
    assert replan_trigger(every, np.array([1.3, 0.0, 0.0]), plan, False, np.array([1.0, 0.0, 0.0]), 5.0) is None
    assert replan_trigger(every, np.array([1.6, 0.0, 0.0]), plan, False, np.array([1.0, 0.0, 0.0]), 5.0).startswith(
        "moved 0.60 m")
    assert replan_trigger(node, here, None, False, np.array([0.0, 0.0, 0.0]), 5.0) == "moved since the last attempt"


# -- figures -----------------------------------------------------------------------------------------------------
def test_smoothness_and_plan_mode_by_hand() -> None:
    assert smoothness(np.array([[0.0, 0.0], [3.0, 0.0]])) == pytest.approx(0.0)
    phi = np.linspace(0, math.pi, 400)
    circle = np.stack([np.sin(phi), 1 - np.cos(phi)], axis=1) * 0.5  # a half circle of radius 0.5 m
    assert smoothness(circle) == pytest.approx(math.degrees(1 / 0.5), rel=0.05)  # 1/r rad per metre (less the ends)
    start = np.array([0.0, 0.0])
    assert plan_mode(arc_l(start, 1.0, 0.3, 1.0, left=True), 0.6) == (1, 0)
    assert plan_mode(arc_l(start, 1.0, 0.9, 1.0, left=True), 0.6) == (1, 1)
    assert plan_mode(arc_l(start, 1.0, 0.9, 1.0, left=False), 0.6) == (-1, 1)
    assert plan_mode(arc_l(start, 1.0, 0.9, 1.0), None) == (1, -1)
    assert plan_mode(np.array([[0.0, 0.0], [3.0, 0.1]]), 0.6) is None  # no turn, no mode


def _episode(sc: Scenario, path: np.ndarray, plans: list[np.ndarray], outcome: str = "success") -> Episode:
    records = [PlanRecord(np.r_[p[0], 0.0], p, False, 0.01, "start") for p in plans]
    return Episode(sc, np.column_stack([path, np.zeros(len(path))]), outcome, records, len(path) - 1)


def test_episode_figures_by_hand() -> None:
    m = open_map()
    demo = arc_l(np.array([2.0, 2.0]), 1.0, 0.3, 1.0)
    wide = arc_l(np.array([2.0, 2.0]), 1.0, 0.9, 1.0)
    sc = scenario(m, demo, alternatives=wide[None])
    shifted = demo + np.array([0.0, 0.1])  # 10 cm off everywhere
    fig = episode_figures(_episode(sc, shifted, [demo, wide, demo]), commit_tol_cm=5.0)
    assert fig["ape_cm"] == pytest.approx(10.0, abs=1e-6)
    assert fig["plausibility_cm"] == pytest.approx(10.0, abs=1e-6) and fig["commit"] == 0.0
    assert fig["mode_switches"] == 2.0  # sharp -> wide -> sharp
    assert fig["replan_change_cm"] > 5.0
    assert fig["plan_ms"] == pytest.approx(10.0) and fig["replans"] == 3.0
    on_wide = episode_figures(_episode(sc, wide, [wide, wide]), commit_tol_cm=5.0)
    assert on_wide["plausibility_cm"] == pytest.approx(0.0, abs=1e-9) and on_wide["commit"] == 1.0
    assert on_wide["ape_cm"] > 10.0 and on_wide["replan_change_cm"] == pytest.approx(0.0, abs=1e-6)
    assert on_wide["mode_switches"] == 0.0 and on_wide["length_ratio"] > 1.0
    failed = episode_figures(_episode(sc, demo[:10], [demo], outcome="collision"))
    assert failed["collision"] == 1.0 and math.isnan(failed["length_ratio"]) and failed["ape_cm"] > 30.0
    no_alts = episode_figures(_episode(scenario(m, demo), demo, [demo]))
    assert no_alts["ape_cm"] == pytest.approx(0.0, abs=1e-9) and math.isnan(no_alts["plausibility_cm"])

    metric = ClosedLoopMetrics(commit_tol_cm=5.0)
    metric.update([_episode(sc, shifted, [demo]), _episode(sc, wide, [wide])])
    metric.update([_episode(sc, demo[:10], [demo], outcome="collision")])
    out = metric.compute()
    assert set(out) == set(CLOSED_LOOP_KEYS)
    assert float(out["success_rate"]) == pytest.approx(2 / 3) and float(out["collision_rate"]) == pytest.approx(1 / 3)
    assert float(out["commit_rate"]) == pytest.approx(1 / 3) and float(out["episodes"]) == 3


def test_scenario_starts_pick_the_longest_remaining_path_per_scenario() -> None:
    long, short = np.array([[0, 0], [0, 10.0]]), np.array([[0, 0], [0, 2.0]])
    ids = ["a", "a", "b", "a", "b"]
    assert scenario_starts(ids, np.stack([short, long, long, short, short])) == [1, 2]
    assert scenario_starts(ids, np.stack([short, long, long, short, short]), indices=[0, 3, 4]) == [0, 4]


# -- whole episodes ------------------------------------------------------------------------------------------------
def test_the_replayed_demonstration_succeeds_and_the_nav2_baseline_drives_to_the_goal() -> None:
    m = open_map()
    sc = scenario(m, arc_l(np.array([2.0, 2.0]), 1.5, 0.5, 1.5))
    (ep,) = replay([sc])
    assert ep.success and episode_figures(ep)["ape_cm"] == pytest.approx(0.0, abs=1e-9)
    settings = ClosedLoopSettings()
    for planner in (BaselinePlanner("shortest", FRAME, 0.1, far_goal="clip"), DemonstrationPlanner([sc])):
        (ep,) = drive(planner, [sc], settings)
        assert ep.success, ep.outcome
        assert np.linalg.norm(ep.path[-1, :2] - sc.goal) <= settings.goal_tolerance_m
        assert len(ep.plans) >= 3  # replanned every 0.5 m
    followed = episode_figures(drive(DemonstrationPlanner([sc]), [sc], settings)[0])
    assert followed["ape_cm"] < 6.0  # the follower's own error: pure pursuit cuts a 0.5 m turn by centimetres


class StraightThrough:
    """A planner that plans the straight line to the goal, obstacles or not."""

    def plan_batch(self, maps, poses, goals, previous=None):  # noqa: ANN001, ANN201
        return [PlanResult(True, np.linspace(np.asarray(p)[:2], np.asarray(g), 32), subgoal=False)
                for p, g in zip(poses, goals)]


class NeverPlans:
    def plan_batch(self, maps, poses, goals, previous=None):  # noqa: ANN001, ANN201
        return [PlanResult(False, np.zeros((0, 2)), code="no_free_path", subgoal=False) for _ in poses]


def test_a_plan_through_an_obstacle_collides_and_a_failed_plan_stops_the_robot() -> None:
    m = open_map(block=(slice(60, 90), slice(40, 46)))  # a wall between start and goal (rows from the top)
    demo = arc_l(np.array([2.0, 2.0]), 1.0, 0.5, 1.0)
    sc = scenario(m, resample_polyline(np.array([[2.0, 2.5], [3.0, 2.5], [6.0, 2.5]]), 64))
    (ep,) = drive(StraightThrough(), [sc], ClosedLoopSettings())
    assert ep.outcome == "collision"
    x, y = ep.path[-1, :2]
    assert 3.6 <= x <= 4.8  # stopped at the wall (columns 40-45: x 4.0-4.6 m, within the robot's radius)
    (ep,) = drive(NeverPlans(), [scenario(m, demo)], ClosedLoopSettings())
    assert ep.outcome == "no_plan" and ep.steps == 0
    (ep,) = drive(BaselinePlanner("shortest", FRAME, 0.1, far_goal="clip"), [sc], ClosedLoopSettings())
    assert ep.success  # the Nav2-like planner goes round it


def test_episodes_are_deterministic_per_seed_under_noise_and_offsets() -> None:
    m = open_map()
    scs = [scenario(m, arc_l(np.array([2.0, 2.0 + k]), 1.5, 0.5, 1.5), sid=f"room/L{k:03d}") for k in range(3)]
    planner = BaselinePlanner("shortest", FRAME, 0.1, far_goal="clip")
    noisy = dict(noise_xy_m=0.03, noise_yaw_rad=0.03, initial_offset_m=0.2, initial_offset_rad=0.3)
    a = drive(planner, scs, ClosedLoopSettings(seed=5, **noisy))
    b = drive(planner, scs, ClosedLoopSettings(seed=5, **noisy))
    c = drive(planner, scs, ClosedLoopSettings(seed=6, **noisy))
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x.path, y.path)
    assert any(x.path.shape != z.path.shape or not np.array_equal(x.path, z.path) for x, z in zip(a, c))
    starts = np.array([e.path[0] for e in a])
    offsets = np.linalg.norm(starts[:, :2] - np.array([s.start[:2] for s in scs]), axis=1)
    np.testing.assert_allclose(offsets, 0.2, atol=1e-9)  # the open room never halves the offset
    assert all(e.success for e in a)  # 3 cm of localisation noise does not stop the Nav2-like planner


def test_closed_loop_settings_refuse_bad_values() -> None:
    with pytest.raises(ValueError, match="noise_xy_m must be a number >= 0"):
        ClosedLoopSettings(noise_xy_m=-1.0)
    with pytest.raises(ValueError, match="goal_tolerance_m must be > 0"):
        ClosedLoopSettings(goal_tolerance_m=0.0)


# -- end to end ------------------------------------------------------------------------------------------------------
@pytest.mark.slow
def test_evaluate_drives_the_test_scenarios_in_closed_loop(spade_home, tiny_checkpoints, tmp_path) -> None:  # noqa: ANN001
    """python -m spade.evaluate closed_loop=true: the student and the baselines drive every test scenario; the
    replayed demonstration scores success 1 and APE 0 (the scenarios are rebuilt right), the Nav2-like planner
    reaches the goal without collision (the simulator is sound); two runs with one seed drive the same paths."""
    from spade.experiments.evaluation import evaluate
    from spade.tracking.summary import closed_loop_lines
    from spade.metrics.closed_loop import CLOSED_LOOP_KEYS
    from spade.utils.config import compose_config

    overrides = [f"ckpt_path={tiny_checkpoints['student']}", "logger=none", "trainer.enable_progress_bar=false",
                 f"paths.output_dir={tmp_path}/eval", "closed_loop=true", "drive.noise_xy_m=0.02"]
    first = evaluate(compose_config("evaluate", [*overrides, f"drive.mcap={tmp_path}/episodes.mcap"]))
    assert (tmp_path / "episodes.mcap").stat().st_size > 0
    for prefix in ("", "baseline/shortest/", "baseline/heading/", "followed/", "demonstration/"):
        assert {f"closed_loop/{prefix}{k}" for k in CLOSED_LOOP_KEYS} <= set(first), prefix
    assert first["closed_loop/episodes"] >= 2
    assert first["closed_loop/demonstration/success_rate"] == 1.0
    assert first["closed_loop/demonstration/ape_cm"] == pytest.approx(0.0, abs=1e-6)
    assert first["closed_loop/baseline/shortest/success_rate"] >= 0.95
    assert first["closed_loop/baseline/shortest/collision_rate"] == 0.0
    assert "test/ape_cm" in first  # the open-loop test ran too
    lines = closed_loop_lines(first)
    assert any("Nav2-like shortest path" in line for line in lines)
    only = evaluate(compose_config("evaluate", [*overrides, "open_loop=false"]))
    assert "test/ape_cm" not in only
    for key in ("closed_loop/ape_cm", "closed_loop/success_rate", "closed_loop/baseline/heading/ape_cm"):
        assert only[key] == first[key], key  # same seed, same noise, same paths
    from spade.utils.errors import ConfigError

    # refused by the drive preflight (spade/config/drive_checks.py) before any run opens
    with pytest.raises(ConfigError, match=r"drive\.noise_xy_m=-0\.1 is out of range; set it to a number >= 0"):
        evaluate(compose_config("evaluate", [*overrides, "drive.noise_xy_m=-0.1"]))
    expert = [f"ckpt_path={tiny_checkpoints['cond']}", *overrides[1:]]
    with pytest.raises(ConfigError, match="closed_loop=true drives a planner"):
        evaluate(compose_config("evaluate", expert))


def test_episodes_are_recorded_for_foxglove_with_the_robots_tf(tmp_path) -> None:  # noqa: ANN001
    import mcap_ros2.reader

    from spade.closedloop.episode_recording import EPISODE_TOPICS, write_episodes_bag

    m = open_map()
    scs = [scenario(m, arc_l(np.array([2.0, 2.0 + k]), 1.0, 0.5, 1.0), sid=f"room/L{k:03d}") for k in range(2)]
    episodes = drive(BaselinePlanner("shortest", FRAME, 0.1, far_goal="clip"), scs, ClosedLoopSettings())
    path = write_episodes_bag(tmp_path / "episodes.mcap", episodes, dt_s=0.1)
    got = [(msg.channel.topic, msg.schema.name, msg.ros_msg, msg.log_time_ns)
           for msg in mcap_ros2.reader.read_ros2_messages(str(path))]
    topics = {t for t, *_ in got}
    assert topics == set(EPISODE_TOPICS) and all(EPISODE_TOPICS[t] == s for t, s, *_ in got)
    steps = sum(len(e.path) for e in episodes)
    tfs = [msg for t, _, msg, _ in got if t == "/tf"]
    assert len(tfs) == steps and sum(t == "/map" for t, *_ in got) == 1  # one map for both episodes
    last = episodes[-1].path[-1]
    tf = tfs[-1].transforms[0]
    assert (tf.header.frame_id, tf.child_frame_id) == ("map", "base_link")
    assert (tf.transform.translation.x, tf.transform.translation.y) == pytest.approx(tuple(last[:2]))
    assert sum(t == "/plan" for t, *_ in got) == sum(len(e.plans) for e in episodes)
    stamps = [ns for t, _, _, ns in got if t == "/robot_pose"]
    assert stamps == sorted(stamps) and stamps[1] - stamps[0] == 100_000_000  # the control period
    with pytest.raises(Exception, match="never written over"):
        write_episodes_bag(path, episodes, dt_s=0.1)


@pytest.mark.slow
def test_an_experts_test_logs_its_planner_spread_against_the_generators(spade_home, tiny_checkpoints,  # noqa: ANN001
                                                                        tmp_path) -> None:  # noqa: ANN001
    """The expert as a planner (issue: a teacher that knows more): a second, independent sample per instance gives the
    spread of its decoded paths beside the generator's (the test set's alternatives)."""
    from spade.experiments.evaluation import evaluate
    from spade.utils.config import compose_config

    metrics = evaluate(compose_config("evaluate", [f"ckpt_path={tiny_checkpoints['cond']}", "logger=none",
                                                   "trainer.enable_progress_bar=false",
                                                   f"paths.output_dir={tmp_path}/eval"]))
    assert metrics["test/planner/spread_cm"] >= 0.0 and math.isfinite(metrics["test/planner/spread_cm"])
    assert metrics["test/generator_spread_cm"] > 0.0  # the tiny test set draws alternatives
    assert math.isfinite(metrics["test/planner/spread_ratio"])
    assert metrics["test/seconds_per_sample"] > 0.0
    # the mean of the K samples' maps, decoded by the planner, beside the one sample
    assert math.isfinite(metrics["test/mean_map/planner/ape_cm"]) and "test/mean_map/planner/plausibility_cm" in metrics


# -- the results page ------------------------------------------------------------------------------------------------
def test_the_closed_loop_page_shows_seeds_baselines_tests_and_the_rankings(tmp_path) -> None:  # noqa: ANN001
    """spade.report table=closed_loop from hand-made drives: mean +/- sd over seeds, the baselines, Welch and paired
    tests with Holm, and where the open-loop and closed-loop rankings disagree."""
    from mlflow import MlflowClient

    from spade.experiments.closed_loop_table import closed_loop_report

    uri = f"sqlite:///{tmp_path}/mlflow.db"
    client = MlflowClient(tracking_uri=uri)
    experiment = client.create_experiment("closed_loop")
    figures = {  # row -> per seed: (closed-loop APE, success, open-loop planner APE)
        "bc": [(10.0, 1.0, 4.0), (11.0, 1.0, 4.2), (12.0, 0.98, 4.1)],
        "cond": [(20.0, 0.9, 3.9), (21.0, 0.92, 3.8), (22.0, 0.9, 3.95)],
    }
    for row, seeds in figures.items():
        for seed, (ape, success, open_ape) in enumerate(seeds):
            tags = {"source_row": row, "dataset": "heldout", "condition": "clean", "scale": "quickstart"}
            if row == "cond":  # the trained run the drive came from, with its margin's activity at the end
                source = client.create_run(experiment, run_name="cond").info.run_id
                client.log_metric(source, "margin/active", 0.25 * seed)
                client.set_tag(source, "mlflow.parentRunId", "a-training-run-is-not-a-drive")
                tags["source_run"] = source
            run = client.create_run(experiment, run_name=f"{row}__heldout__clean", tags=tags)
            rid = run.info.run_id
            client.log_param(rid, "cfg/seed", seed)
            metrics = {"closed_loop/ape_cm": ape, "closed_loop/success_rate": success,
                       "closed_loop/episodes": 100.0, "test/planner/ape_cm": open_ape,
                       "closed_loop/baseline/shortest/ape_cm": 40.0 + seed,
                       "closed_loop/baseline/shortest/success_rate": 1.0}
            for key, value in metrics.items():
                client.log_metric(rid, key, value)
            client.set_terminated(rid, "FINISHED")
    text, files = closed_loop_report(uri, tmp_path / "out", "quickstart", labels={"bc": "BC", "cond": "Cond-DBC"})
    assert "### heldout, clean (100 scenarios)" in text
    assert "| BC | 3 | 99% ± 1 pt | n/a | n/a | 11.00 ± 1.00 |" in text
    assert "| *Nav2-like shortest path* | 6 |" in text
    rows = {line.split(" | ")[0]: line for line in text.splitlines() if line.startswith("| BC |")
            or line.startswith("| Cond-DBC |")}
    assert rows["| BC"].endswith("| no margin |")
    assert rows["| Cond-DBC"].endswith("| 25.0% ± 25 pt |")  # 0, 25 and 50 % over its three seeds
    assert "by open-loop planner APE: Cond-DBC < BC; by closed-loop APE: BC < Cond-DBC: **they disagree**" in text
    welch = next(line for line in text.splitlines() if line.startswith("| heldout, clean: BC vs Cond-DBC | ape_cm"))
    assert "Welch" in welch and "| significant |" in welch  # 10 cm apart with sd 1: p about 2e-4 before Holm
    assert ("heldout, clean: BC against Cond-DBC: success 99.3% vs 90.7% (higher, significant); APE 11.00 cm vs "
            "21.00 cm (lower, significant): **BC wins**") in text
    assert "BC against Nav2-like shortest path:" in text
    assert files["markdown"].read_text() == text and files["csv"].is_file()
    empty, _ = closed_loop_report(f"sqlite:///{tmp_path}/other.db", None)
    assert "launch them with `python -m spade.closed_loop`" in empty


@pytest.mark.slow
def test_a_training_run_drives_its_best_checkpoint_when_the_scale_says_so(spade_home) -> None:  # noqa: ANN001
    """closed_loop: true (the quickstart's scale): after its test, spade.train drives the test scenarios; the run
    carries the worst episodes' picture and the episodes file as spade.evaluate's does, each baseline's child run its
    closed-loop figures under the student's names, and the description the closed loop's verdict."""
    from mlflow import MlflowClient

    from spade.experiments.run import train
    from spade.tracking.predictors import NOTE_TAG, PARENT_TAG, PREDICTOR_TAG
    from training_helpers import compose_row

    cfg = compose_row("t1_medium_bc_L", spade_home, "trainer.max_steps=2", "trainer.max_epochs=1",
                      "+trainer.limit_val_batches=1", "data.eval_batch_size=8", "model.grid_size=0",
                      "callbacks.model_info.latency_runs=0", "closed_loop=true", "tags.table=closed_loop_train_check")
    metrics, objects = train(cfg)
    assert metrics["closed_loop/demonstration/success_rate"] == 1.0
    assert 0.0 <= metrics["closed_loop/success_rate"] <= 1.0 and "test/ape_cm" in metrics
    client, run_id = MlflowClient(tracking_uri=str(cfg.paths.mlflow_tracking_uri)), objects["run"].run_id
    assert sorted(a.path for a in client.list_artifacts(run_id, "closed_loop")) == [
        "closed_loop/episodes.json", "closed_loop/worst.png"]
    run = client.get_run(run_id)
    children = {r.data.tags[PREDICTOR_TAG]: r.data.metrics for r in client.search_runs(
        [run.info.experiment_id], filter_string=f"tags.`{PARENT_TAG}` = '{run_id}'")}
    for name in ("shortest", "heading"):
        assert children[f"baseline-{name}"]["closed_loop/ape_cm"] == pytest.approx(
            metrics[f"closed_loop/baseline/{name}/ape_cm"]), name
    assert "**Closed loop.** Success " in run.data.tags[NOTE_TAG]


def test_a_changed_condition_reruns_its_drives_and_the_page_drops_the_old_numbers(tmp_path: Path,
                                                                                  monkeypatch) -> None:
    """Drives were matched by name and source run only, and recorded no noise or offset: a changed
    perturbation printed "0 drives run" and the page kept the old numbers under "perturbed". Now each drive is
    keyed by its full settings (recorded with it): a changed setting reruns exactly the drives it changes, and the
    page shows each cell's latest settings only. The drive itself (spade.evaluate) is replaced by a stand-in that
    records a finished run with the tags it is given."""
    from types import SimpleNamespace

    from mlflow import MlflowClient

    import spade.experiments.closed_loop_table as table
    from spade.utils.config import compose_config

    uri = f"sqlite:///{tmp_path}/mlflow.db"
    client = MlflowClient(tracking_uri=uri)
    experiment = client.create_experiment(table.CLOSED_LOOP_TABLE)
    driven: list[dict] = []

    def drive(cfg) -> dict:  # noqa: ANN001 - spade.evaluate's stand-in
        noise = float(cfg.drive.noise_xy_m)
        tags = {k: str(v) for k, v in cfg.tags.items()}
        run = client.create_run(experiment, run_name=str(cfg.run_name), tags=tags)
        client.log_param(run.info.run_id, "cfg/seed", int(cfg.seed))
        client.log_metric(run.info.run_id, "closed_loop/ape_cm", 100.0 * noise + 1.0)
        client.log_metric(run.info.run_id, "closed_loop/success_rate", 1.0)
        client.set_terminated(run.info.run_id, "FINISHED")
        driven.append({"condition": tags["condition"], "noise": noise, "settings": json.loads(tags["drive_settings"])})
        return {"closed_loop/success_rate": 1.0, "closed_loop/ape_cm": 100.0 * noise + 1.0}

    source = SimpleNamespace(info=SimpleNamespace(run_id="source-run-1"), data=SimpleNamespace(params={"cfg/seed": "0"}))
    monkeypatch.setattr(table, "evaluate", drive)
    monkeypatch.setattr(table, "source_runs", lambda *args: [source])
    monkeypatch.setattr(table, "_best_checkpoint", lambda *args: tmp_path / "best.ckpt")

    def launch(noise: float) -> list[dict]:
        from omegaconf import OmegaConf

        cfg = compose_config("closed_loop", [f"tracking_uri={uri}", f"paths.output_dir={tmp_path}/out"])
        cfg.sources = [{"table": "guidance", "row": "bc"}]
        cfg.datasets = {"heldout": {"data": "lshape", "scenarios": 3}}
        cfg.conditions = OmegaConf.create({"clean": {}, "perturbed": {"noise_xy_m": noise}})
        return table.launch(cfg)

    assert [r["run"] for r in launch(0.03)] == ["bc__heldout__clean", "bc__heldout__perturbed"]
    assert driven[-1]["settings"]["drive"]["noise_xy_m"] == 0.03  # the settings are recorded with the drive
    assert launch(0.03) == []  # the same settings: nothing to run
    assert [r["run"] for r in launch(0.1)] == ["bc__heldout__perturbed"]  # the changed condition alone reruns
    assert driven[-1]["noise"] == 0.1
    cells = table.fetch_drives(uri)
    assert cells[("bc", "heldout", "perturbed")].values("closed_loop/ape_cm") == [pytest.approx(11.0)]
    assert cells[("bc", "heldout", "clean")].values("closed_loop/ape_cm") == [pytest.approx(1.0)]
    # a second seed driven under the earlier settings, finishing last: its settings are now the cell's latest, and
    # the cell shows the drives of those settings alone (both seeds at 0.03), never the 0.1 drive beside them
    old = next(r for r in client.search_runs([experiment], "attributes.run_name = 'bc__heldout__perturbed'")
               if r.data.tags["drive_settings"] and json.loads(r.data.tags["drive_settings"])["drive"]["noise_xy_m"] == 0.03)
    late = client.create_run(experiment, run_name="bc__heldout__perturbed", tags=old.data.tags)
    client.log_param(late.info.run_id, "cfg/seed", 1)
    client.log_metric(late.info.run_id, "closed_loop/ape_cm", 4.0)
    client.set_terminated(late.info.run_id, "FINISHED")
    assert table.fetch_drives(uri)[("bc", "heldout", "perturbed")].values("closed_loop/ape_cm") == [4.0, 4.0]
