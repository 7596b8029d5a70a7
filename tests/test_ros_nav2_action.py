"""python -m spade.ros as Nav2's planner server, on loopback DDS: a ComputePathToPose client written from the
documented definitions (spade.ros.action.ActionClient) sends goals (valid, occupied, outside the map, canceled,
from the robot's pose) and gets results with the right status and error codes, in the Jazzy and the Humble
layouts; and the desk simulator (python -m spade.ros sim) drives the node's robot to its goals.
(Not a real Nav2: no bt_navigator here; docs/deployment.md says what that leaves untested.)"""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from ros_support import loopback_env, student_files, unique_domain, wait_for

pytestmark = [pytest.mark.slow]


@pytest.fixture(scope="module")
def student(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    pytest.importorskip("onnxruntime")
    return student_files(tmp_path_factory.mktemp("student"))


def room_map(folder: Path) -> Path:
    """A 10 x 8 m room at 0.05 m/cell: walls around it, a 1 x 1 m block at x 6..7, y 4..5."""
    from spade.maps import FREE, OCCUPIED, OccupancyMap, save_ros_map

    grid = np.full((160, 200), FREE, np.uint8)
    grid[:2, :] = grid[-2:, :] = OCCUPIED
    grid[:, :2] = grid[:, -2:] = OCCUPIED
    grid[160 - 100:160 - 80, 120:140] = OCCUPIED  # rows count from the top: y 4..5 m, x 6..7 m
    m = OccupancyMap(grid, 0.05, (0.0, 0.0, 0.0), name="room")
    return save_ros_map(m, folder / "room.yaml")


def start_node(tmp_path: Path, onnx: Path, domain: int, *extra: str) -> tuple[subprocess.Popen, Path, dict]:
    env = loopback_env(tmp_path)
    log = tmp_path / "node.log"
    with open(log, "w") as out:
        node = subprocess.Popen([sys.executable, "-m", "spade.ros", f"model={onnx}", f"domain_id={domain}", *extra],
                                cwd=tmp_path, env=env, stdout=out, stderr=subprocess.STDOUT)
    return node, log, env


def stop(node: subprocess.Popen) -> None:
    node.terminate()
    try:
        node.wait(30)
    except subprocess.TimeoutExpired:
        node.kill()


@pytest.mark.timeout(240)
@pytest.mark.parametrize("distro", ["jazzy", "humble"])
def test_compute_path_to_pose_over_dds(tmp_path: Path, student: tuple[Path, Path], distro: str,
                                       monkeypatch: pytest.MonkeyPatch) -> None:
    pytest.importorskip("cyclonedds")
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.pub import DataWriter
    from cyclonedds.topic import Topic

    from spade.maps import load_ros_map
    from spade.ros import messages as M
    from spade.ros.action import ActionClient
    from spade.ros.action_types import CANCEL, ERROR, STATUS
    from spade.ros.dds import make_qos

    m = load_ros_map(room_map(tmp_path))
    domain = unique_domain() + (1 if distro == "humble" else 0)
    node, log, env = start_node(tmp_path, student[1], domain, "action.enabled=true", f"action.distro={distro}",
                                "action.wait_s=30")
    monkeypatch.setenv("CYCLONEDDS_URI", env["CYCLONEDDS_URI"])
    try:
        p = DomainParticipant(domain)
        client = ActionClient(p, "/compute_path_to_pose", distro)
        assert client.wait_for_server(120), log.read_text()
        # 1. Before any map: the goal waits (use_start false, no pose either); cancel it.
        gid, reply = client.send_goal((3.0, 2.0, 0.0))
        assert reply.accepted
        canceled = client.cancel(gid)
        assert canceled.return_code == CANCEL.ERROR_NONE and bytes(canceled.goals_canceling[0].goal_id.uuid) == gid
        assert client.get_result(gid).status == STATUS.CANCELED
        assert client.cancel(gid).return_code == CANCEL.ERROR_GOAL_TERMINATED
        assert client.cancel(bytes([7] * 16)).return_code == CANCEL.ERROR_UNKNOWN_GOAL_ID
        # 2. The map, then goals from a given start.
        map_writer = DataWriter(p, Topic(p, "rt/map", M.OccupancyGrid), qos=make_qos(True, True, 1))
        map_writer.write(M.occupancy_grid(m, "map"))
        wait_for(log, "map received", 60)
        t0 = time.perf_counter()
        ok = client.plan((3.5, 2.5, 0.0), start=(2.0, 2.0, 0.0))
        seconds = time.perf_counter() - t0
        assert ok.status == STATUS.SUCCEEDED, log.read_text()
        xy = np.array([[q.pose.position.x, q.pose.position.y] for q in ok.result.path.poses])
        assert ok.result.path.header.frame_id == "map" and len(xy) >= 2
        assert np.linalg.norm(xy[0] - [2.0, 2.0]) < 0.15 and np.linalg.norm(xy[-1] - [3.5, 2.5]) < 0.15
        planning = ok.result.planning_time.sec + ok.result.planning_time.nanosec * 1e-9
        assert 0 < planning < seconds
        if distro == "jazzy":
            assert ok.result.error_code == ERROR.NONE and ok.result.error_msg == ""
        failures = {(6.5, 4.5, 0.0): ERROR.GOAL_OCCUPIED, (12.0, 2.0, 0.0): ERROR.GOAL_OUTSIDE_MAP}
        for goal, code in failures.items():
            bad = client.plan(goal, start=(5.0, 4.5, 0.0))
            assert bad.status == STATUS.ABORTED and not bad.result.path.poses
            if distro == "jazzy":
                assert bad.result.error_code == code and bad.result.error_msg
            else:
                assert not hasattr(bad.result, "error_code")  # Humble: the ABORTED status alone
        start_bad = client.plan((2.0, 2.0, 0.0), start=(-1.0, 2.0, 0.0))
        assert start_bad.status == STATUS.ABORTED
        if distro == "jazzy":
            assert start_bad.result.error_code == ERROR.START_OUTSIDE_MAP
        # 3. From the robot's latest pose (use_start false), as Nav2's BT asks.
        pose_writer = DataWriter(p, Topic(p, "rt/amcl_pose", M.PoseWithCovarianceStamped), qos=make_qos(True, True, 1))
        pose_writer.write(M.pose_with_covariance((2.0, 3.0, 0.0), "map"))
        wait_for(log, "robot pose received", 60)
        from_pose = client.plan((3.5, 3.0, 0.0))
        assert from_pose.status == STATUS.SUCCEEDED
        first = from_pose.result.path.poses[0].pose.position
        assert abs(first.x - 2.0) < 0.15 and abs(first.y - 3.0) < 0.15
        assert client.get_result(bytes([9] * 16)).status == STATUS.UNKNOWN
        out = log.read_text()
        assert "action /compute_path_to_pose" in out and "GOAL_OCCUPIED (206)" in out and "Traceback" not in out
    finally:
        stop(node)


@pytest.mark.timeout(300)
@pytest.mark.parametrize("use_action", [False, True])
def test_the_desk_simulator_drives_the_node_to_its_goals(tmp_path: Path, student: tuple[Path, Path],
                                                         use_action: bool) -> None:
    """python -m spade.ros sim map=... model=... starts the node, follows its plans and reaches both goals."""
    pytest.importorskip("cyclonedds")
    env = loopback_env(tmp_path)
    domain = unique_domain() + 2 + int(use_action)
    args = [sys.executable, "-m", "spade.ros", "sim", f"map={room_map(tmp_path)}", f"model={student[1]}",
            f"domain_id={domain}", "start=[2.0,2.0,0.0]", "goals=[[3.5,2.3,0.0],[4.0,3.5,1.5]]",
            "goal_timeout_s=60", "speed_mps=0.5", f"use_action={'true' if use_action else 'false'}"]
    run = subprocess.run(args, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=280)
    out = run.stdout + run.stderr
    assert run.returncode == 0, out
    assert "sim: 2/2 goals reached" in out and "0 collisions" in out
    assert "Traceback" not in out
