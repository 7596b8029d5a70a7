"""ROS 2 MCAP recordings: plans written with rosbags and decoded with mcap-ros2-support (as Foxglove reads them), and
recordings of a robot's map, pose and goals replayed through the planner node's logic offline."""

from __future__ import annotations

import logging
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from spade.maps import generate_map
from spade.planner import PlanResult
from spade.ros.convert import grid_to_map, quaternion_to_yaw
from spade.ros.core import CoreSettings, PlannerCore
from spade.ros.recording import BagError, replay_bag, write_plan_bag
from ros_support import robot_bag

mcap_ros2 = pytest.importorskip("mcap_ros2.reader")
REPO = Path(__file__).resolve().parents[1]


def decode(path: Path) -> list[tuple[str, str, object, int]]:
    """(topic, type, message, log time) of every message of an MCAP file, decoded by mcap-ros2-support."""
    return [(m.channel.topic, m.schema.name, m.ros_msg, m.log_time_ns) for m in mcap_ros2.read_ros2_messages(str(path))]


def mcap_file(path: Path) -> Path:
    return path if path.suffix == ".mcap" else next(path.glob("*.mcap"))


def a_plan() -> PlanResult:
    pts = np.column_stack([np.linspace(2.0, 4.0, 16), np.linspace(3.0, 3.5, 16)])
    return PlanResult(success=True, waypoints=pts, pose=np.array([2.0, 3.0, 0.2]), start=pts[0], goal=pts[-1],
                      low_share=0.25)


@pytest.mark.parametrize("name", ["plan.mcap", "plan_bag"])
def test_a_plan_bag_decodes_with_mcap_ros2_support(tmp_path: Path, name: str) -> None:
    m = generate_map("warehouse", 2)
    failed = PlanResult(success=False, waypoints=np.zeros((0, 2)), code="goal_outside_map", reason="off the map",
                        pose=np.array([2.0, 3.0, 0.0]), goal=np.array([99.0, 99.0]))
    out = write_plan_bag(tmp_path / name, m, [a_plan(), failed], start_ns=1_700_000_000_000_000_000,
                         goal_yaws=[0.5, 0.0])
    assert out == tmp_path / name
    if name == "plan_bag":  # a rosbag2 folder, as ros2 bag record -s mcap writes one
        assert (out / "metadata.yaml").is_file() and "offered_qos_profiles" in (out / "metadata.yaml").read_text()
    assert not list(tmp_path.glob(".spade-bag-*")), "the temporary folder was left behind"
    got = decode(mcap_file(out))
    topics = [(t, s) for t, s, _, _ in got]
    assert topics == [("/map", "nav_msgs/msg/OccupancyGrid"), ("/start_pose", "geometry_msgs/msg/PoseStamped"),
                      ("/goal_pose", "geometry_msgs/msg/PoseStamped"), ("/plan", "nav_msgs/msg/Path"),
                      ("/plan_confidence", "std_msgs/msg/Float32"), ("/start_pose", "geometry_msgs/msg/PoseStamped"),
                      ("/goal_pose", "geometry_msgs/msg/PoseStamped")]  # the failed plan: its poses, no path
    grid = got[0][2]
    np.testing.assert_array_equal(grid_to_map(grid).grid, m.grid)  # the map as ROS 2 carries it, rows and all
    path = got[3][2]
    assert path.header.frame_id == "map" and len(path.poses) == 16
    assert (path.header.stamp.sec, path.header.stamp.nanosec) == (1_700_000_000, 0)
    xy = np.array([[p.pose.position.x, p.pose.position.y] for p in path.poses])
    np.testing.assert_allclose(xy, a_plan().waypoints)
    q = path.poses[-1].pose.orientation
    assert quaternion_to_yaw(q.x, q.y, q.z, q.w) == pytest.approx(0.5)
    assert got[4][2].data == pytest.approx(0.75)
    assert [t for *_, t in got] == sorted(t for *_, t in got) and got[-1][3] == 1_700_000_001_000_000_000
    with pytest.raises(BagError, match="never written over"):
        write_plan_bag(out, m, [a_plan()])


class LinePlanner:
    def plan(self, m, pose, goal, previous=None):  # noqa: ANN001, ANN201
        pts = np.linspace(pose[:2], goal, 8)
        return PlanResult(success=True, waypoints=pts, pose=np.asarray(pose), goal=np.asarray(goal), low_share=0.0)


@pytest.mark.parametrize("name", ["robot.mcap", "robot_bag"])
def test_replaying_a_recording_through_the_node_logic(tmp_path: Path, name: str,
                                                     caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.INFO, logger="spade.ros")
    bag = robot_bag(tmp_path / name)

    class OffMap(LinePlanner):
        def plan(self, m, pose, goal, previous=None):  # noqa: ANN001, ANN201
            if goal[0] > 50:
                return PlanResult(success=False, waypoints=np.zeros((0, 2)), code="goal_outside_map", reason="off")
            return super().plan(m, pose, goal)

    core = PlannerCore(OffMap(), CoreSettings(replan_distance_m=0.5, min_replan_interval_s=0.0))
    counts = replay_bag(core, bag, {"map": "/map", "pose": "/amcl_pose", "goal": "/goal_pose"},
                        out=tmp_path / "replayed.mcap")
    # One plan for the goal, one when the drift took the robot 0.5 m off it, none for the goal off the map.
    assert counts == {"map": 1, "pose": 10, "goal": 2, "plan": 2, "no_path": 1}
    got = decode(tmp_path / "replayed.mcap")
    plans = [(msg, t) for topic, _, msg, t in got if topic == "/plan"]
    assert len(plans) == 2
    first, second = plans
    assert first[1] == 1_700_000_000_000_000_001  # planned when the goal arrived, stamped with the recording's clock
    assert (first[0].header.stamp.sec, first[0].header.stamp.nanosec) == (1_700_000_000, 1)
    assert second[0].poses[0].pose.position.x == pytest.approx(2.6) and second[1] == 1_700_000_006_000_000_000
    assert {topic for topic, *_ in got} == {"/map", "/amcl_pose", "/goal_pose", "/plan"}
    assert "off the plan by 0.60 m" in caplog.text and "goal_outside_map" in caplog.text


def test_replay_refuses_what_it_cannot_replay(tmp_path: Path) -> None:
    core = PlannerCore(LinePlanner())
    with pytest.raises(BagError, match="does not exist"):
        replay_bag(core, tmp_path / "nothing.mcap")
    (tmp_path / "junk.mcap").write_bytes(b"not a bag")
    with pytest.raises(BagError, match="cannot be read as a rosbag2"):
        replay_bag(core, tmp_path / "junk.mcap")
    bag = robot_bag(tmp_path / "robot.mcap")
    with pytest.raises(BagError, match=r"has no /costmap topic \(topics: /amcl_pose"):
        replay_bag(core, bag, {"map": "/costmap"})


@pytest.mark.slow
@pytest.mark.timeout(240)
def test_plan_command_writes_an_mcap(tmp_path: Path, maps_dir: Path) -> None:
    """python -m spade.plan ... mcap=plan.mcap: the plan a robotics person opens in Foxglove."""
    pytest.importorskip("onnxruntime")
    from ros_support import GOAL, MAP, POSE, loopback_env, student_files

    _, onnx = student_files(tmp_path)
    env = loopback_env(tmp_path)
    args = [sys.executable, "-m", "spade.plan", str(maps_dir.joinpath(*MAP)), "start={},{},{}".format(*POSE),
            "goal={},{}".format(*GOAL[:2]), f"model={onnx}", f"out={tmp_path / 'plan.png'}"]
    run = subprocess.run([*args, f"mcap={tmp_path / 'plan.mcap'}"], cwd=tmp_path, env=env, capture_output=True,
                         text=True, timeout=180)
    assert run.returncode == 0, run.stderr
    assert f"# recording: {tmp_path / 'plan.mcap'}" in run.stdout
    got = {topic: msg for topic, _, msg, _ in decode(tmp_path / "plan.mcap")}
    assert set(got) == {"/map", "/start_pose", "/goal_pose", "/plan", "/plan_window", "/plan_confidence"}
    waypoints = [line.split() for line in run.stdout.splitlines() if line and not line.startswith("#")]
    xy = np.array([[p.pose.position.x, p.pose.position.y] for p in got["/plan"].poses])
    np.testing.assert_allclose(xy, np.array(waypoints, dtype=float), atol=1e-3)  # the printed waypoints (3 decimals)
    assert len(got["/plan_window"].polygon.points) == 4
    # A recording is never written over: refused before planning, one line, exit 2.
    again = subprocess.run([*args, "overwrite=true", f"mcap={tmp_path / 'plan.mcap'}"], cwd=tmp_path, env=env,
                           capture_output=True, text=True, timeout=180)
    assert again.returncode == 2 and again.stderr.startswith("error: mcap=") and "never written over" in again.stderr
    assert math.isfinite(got["/plan_confidence"].data)


# -- a test set's predictions (spade.evaluate ... mcap=) ---------------------------------------------------------------
TEST_TOPIC_TYPES = {"/window": "nav_msgs/msg/OccupancyGrid", "/ground_truth": "nav_msgs/msg/Path",
                    "/goal_pose": "geometry_msgs/msg/PoseStamped", "/prediction": "nav_msgs/msg/Path",
                    "/prediction/planner": "nav_msgs/msg/Path", "/baseline/straight": "nav_msgs/msg/Path",
                    "/baseline/shortest": "nav_msgs/msg/Path", "/baseline/heading": "nav_msgs/msg/Path",
                    "/ape_cm": "std_msgs/msg/Float32"}


def path_xy(msg: object) -> np.ndarray:
    return np.array([[p.pose.position.x, p.pose.position.y] for p in msg.poses])  # type: ignore[attr-defined]


def cell_code(grid_msg: object, x: float, y: float) -> int:
    """The code (spade.maps.occupancy) of the cell of a decoded OccupancyGrid holding point (x, y) of its frame."""
    m = grid_to_map(grid_msg)
    col = int(np.floor((x - m.origin[0]) / m.resolution))
    row = m.height - 1 - int(np.floor((y - m.origin[1]) / m.resolution))  # the map's row 0 is its top
    return int(m.grid[row, col])


def hand_made_instances() -> dict:
    """Two robot-frame windows (8 rows x 6 columns, the robot at pixel (3, 6) heading up the image)."""
    occupancy = np.ones((2, 8, 6), dtype=np.uint8)
    occupancy[:, 0, 0] = 2  # an obstacle far ahead, on the robot's left
    occupancy[:, 7, 5] = 0  # unknown behind, on its right
    truth = np.array([[[3.0, 6.0], [3.0, 4.0], [3.0, 1.0]], [[3.0, 6.0], [2.0, 3.0], [1.0, 1.0]]])
    return dict(occupancy=occupancy, ground_truth=truth, goals=truth[:, -1], resolution=[0.1, 0.05],
                robot_px=(3.0, 6.0), predictions=[truth[0] + [0.5, 0.0], None], planner=[truth[0], truth[1]],
                baselines={"straight": [truth[0, [0, -1]], truth[1, [0, -1]]], "shortest": [None, truth[1]],
                           "heading": list(truth)}, ape_cm=[5.0, float("nan")])


def test_a_test_set_bag_decodes_with_mcap_ros2_support(tmp_path: Path) -> None:
    from spade.ros.recording import write_test_bag
    from spade.ros.window_messages import window_to_base_link

    data = hand_made_instances()
    t0 = 1_700_000_000_000_000_000
    out = write_test_bag(tmp_path / "test.mcap", start_ns=t0, **data)
    assert out == tmp_path / "test.mcap" and not list(tmp_path.glob(".spade-bag-*"))
    got = decode(out)
    assert {topic: schema for topic, schema, _, _ in got} == TEST_TOPIC_TYPES
    counts = {topic: sum(t == topic for t, *_ in got) for topic in TEST_TOPIC_TYPES}
    # a failed extraction and a baseline without a path write an empty Path (a viewer clears the last one); a NaN
    # APE writes nothing at that instant
    assert counts == {"/window": 2, "/ground_truth": 2, "/goal_pose": 2, "/prediction": 2, "/prediction/planner": 2,
                      "/baseline/straight": 2, "/baseline/shortest": 2, "/baseline/heading": 2, "/ape_cm": 1}
    assert len(at_empty := [m for t, _, m, _ in got if t == "/prediction" and not m.poses]) == 1, at_empty
    assert sorted({t for *_, t in got}) == [t0, t0 + 1_000_000_000]  # one instance a second
    assert all(msg.header.frame_id == "base_link" for _, schema, msg, _ in got if schema != "std_msgs/msg/Float32")
    at = {(topic, t): msg for topic, _, msg, t in got}
    for i, ns in enumerate((t0, t0 + 1_000_000_000)):
        res = data["resolution"][i]
        xy = path_xy(at["/ground_truth", ns])
        np.testing.assert_allclose(xy, window_to_base_link(data["ground_truth"][i], (3.0, 6.0), res), atol=1e-9)
        np.testing.assert_allclose(xy[0], [0.0, 0.0], atol=1e-12)  # the robot is base_link's origin
        # pixel (3, 1): 5 rows ahead of the robot, in line with it; (1, 1): 5 ahead, 2 to the left
        assert np.allclose(xy[-1], [5 * res, 0.0] if i == 0 else [5 * res, 2 * res])
        goal = at["/goal_pose", ns].pose.position
        assert (goal.x, goal.y) == pytest.approx(tuple(xy[-1]))
        grid = at["/window", ns]
        assert (grid.info.width, grid.info.height) == (8, 6) and grid.info.resolution == pytest.approx(res)
        assert cell_code(grid, 6 * res, 3 * res) == 2  # window pixel (0, 0): ahead and left
        assert cell_code(grid, -1 * res, -2 * res) == 0  # window pixel (5, 7): behind and right
        assert cell_code(grid, 0.0, 0.0) == 1
    np.testing.assert_allclose(path_xy(at["/prediction", t0]),
                               window_to_base_link(data["predictions"][0], (3.0, 6.0), 0.1), atol=1e-9)
    assert at["/ape_cm", t0].data == pytest.approx(5.0)
    with pytest.raises(BagError, match="never written over"):
        write_test_bag(out, **data)
    with pytest.raises(ValueError, match="holds 1 values for 2 instances"):
        write_test_bag(tmp_path / "bad.mcap", **{**data, "ape_cm": [1.0]})


def test_evaluate_writes_the_test_set_as_an_mcap(spade_home: Path, tiny_checkpoints: dict, tmp_path: Path) -> None:
    """python -m spade.evaluate ckpt_path=... mcap=test.mcap: the test set's first instances, the student's paths next
    to the demonstrations and the baselines, in the robot frame; an existing path is refused before the test."""
    from spade.experiments.evaluation import evaluate
    from spade.utils.config import compose_config
    from spade.utils.errors import ConfigError

    out = tmp_path / "test.mcap"
    overrides = [f"ckpt_path={tiny_checkpoints['student']}", "logger=none", "trainer.enable_progress_bar=false",
                 f"paths.output_dir={tmp_path}/eval", "mcap_instances=1000"]
    metrics = evaluate(compose_config("evaluate", [*overrides, f"mcap={out}"]))
    assert "test/ape_cm" in metrics
    got = decode(out)
    topics = {topic for topic, *_ in got}
    assert {"/window", "/ground_truth", "/goal_pose", "/baseline/straight", "/baseline/heading"} <= topics
    assert topics <= set(TEST_TOPIC_TYPES)
    n = int(metrics["test/instances"])  # mcap_instances is more than the tiny test set holds: all of it
    stamps = sorted({t for *_, t in got})
    assert len(stamps) == n and all(b - a == 1_000_000_000 for a, b in zip(stamps, stamps[1:]))
    for topic in ("/window", "/ground_truth", "/goal_pose", "/baseline/straight"):
        assert sum(t == topic for t, *_ in got) == n, topic
    assert all(msg.header.frame_id == "base_link" for _, schema, msg, _ in got if schema != "std_msgs/msg/Float32")
    truth = [msg for topic, _, msg, _ in got if topic == "/ground_truth"]
    assert all(np.allclose(path_xy(msg)[0], [0.0, 0.0], atol=0.05) for msg in truth)  # paths start at the robot
    goals = [msg for topic, _, msg, _ in got if topic == "/goal_pose"]
    for path, goal in zip(truth, goals):
        assert np.linalg.norm(path_xy(path)[-1] - [goal.pose.position.x, goal.pose.position.y]) < 0.3
    windows = [msg for topic, _, msg, _ in got if topic == "/window"]
    assert all(cell_code(grid, x, y) != 2 for path, grid in zip(truth, windows) for x, y in path_xy(path))
    # the paths the test's metrics score: every instance recorded, their APE averages to the test's
    apes = [msg.data for topic, _, msg, _ in got if topic == "/ape_cm"]
    assert len(apes) == metrics["test/instances"] - metrics["test/failures"]
    assert sum(topic == "/prediction" and bool(msg.poses) for topic, _, msg, _ in got) == len(apes)
    if apes:
        assert np.mean(apes) == pytest.approx(metrics["test/ape_cm"], rel=1e-5)
    with pytest.raises(ConfigError, match=r"^mcap=.* exists: a recording is never written over"):
        evaluate(compose_config("evaluate", [*overrides, f"mcap={out}"]))


def test_evaluate_refuses_a_recording_path_it_cannot_write(tmp_path: Path) -> None:
    from spade.experiments.prediction_recording import check_recording_instances
    from spade.ros.recording import check_recording_path
    from spade.utils.errors import ConfigError

    assert check_recording_path(None) is None and check_recording_path("") is None
    assert check_recording_path(str(tmp_path / "new.mcap")) == tmp_path / "new.mcap"
    (tmp_path / "old.mcap").write_bytes(b"")
    with pytest.raises(ConfigError, match="never written over"):
        check_recording_path(str(tmp_path / "old.mcap"))
    with pytest.raises(ConfigError, match="does not exist"):
        check_recording_path(str(tmp_path / "no" / "such.mcap"))
    assert check_recording_instances(3) == 3
    for bad in (0, -1, 2.5, True, "many"):
        with pytest.raises(ConfigError, match="mcap_instances"):
            check_recording_instances(bad)
