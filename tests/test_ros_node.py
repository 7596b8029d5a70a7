"""python -m spade.ros as a process on DDS: a second participant on loopback plays the robot (a real map, AMCL's pose,
RViz2's goal) and checks the nav_msgs/Path it receives; a malformed map and a goal off the map are logged and survived.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from ros_support import GOAL, MAP, POSE, loopback_env, student_files, unique_domain, wait_for

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def student(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """(checkpoint, ONNX export) of an untrained student (module-scoped: exporting sets torch's cache variables)."""
    return student_files(tmp_path_factory.mktemp("student"))


def free_along(m, points: np.ndarray, step_m: float = 0.01) -> bool:
    """Whether the polyline through ``points`` (metres) stays on FREE cells of ``m``, sampled every ``step_m``."""
    from spade.maps import FREE

    dense = [points[:1]]
    for a, b in zip(points[:-1], points[1:]):
        n = max(2, int(np.ceil(np.linalg.norm(b - a) / step_m)) + 1)
        dense.append(np.linspace(a, b, n)[1:])
    cols, rows = np.rint(m.world_to_pixel(np.vstack(dense))).astype(int).T
    return bool((m.grid[rows, cols] == FREE).all())


class Robot:
    """The second DDS participant: publishes map, pose and goals as map_server, AMCL and RViz2 do; reads /plan."""

    def __init__(self, domain: int) -> None:
        from cyclonedds.domain import DomainParticipant
        from cyclonedds.pub import DataWriter
        from cyclonedds.sub import DataReader
        from cyclonedds.topic import Topic

        from spade.ros import messages as M
        from spade.ros.dds import make_qos

        self.M = M
        p = self.participant = DomainParticipant(domain)
        self.map = DataWriter(p, Topic(p, "rt/map", M.OccupancyGrid), qos=make_qos(True, True, 1))
        self.pose = DataWriter(p, Topic(p, "rt/amcl_pose", M.PoseWithCovarianceStamped), qos=make_qos(True, True, 1))
        self.goal = DataWriter(p, Topic(p, "rt/goal_pose", M.PoseStamped), qos=make_qos(True, False, 10))
        self.plan = DataReader(p, Topic(p, "rt/plan", M.Path), qos=make_qos(True, False, 10))
        self.confidence = DataReader(p, Topic(p, "rt/plan_confidence", M.Float32), qos=make_qos(True, False, 10))

    def wait_matched(self, timeout: float, node: subprocess.Popen) -> None:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if self.goal.get_matched_subscriptions() and self.plan.get_matched_publications():
                return
            assert node.poll() is None, "the node exited"
            time.sleep(0.05)
        raise AssertionError("the node's goal subscription and plan publication never matched")

    def paths(self, seconds: float) -> list:
        end, got = time.monotonic() + seconds, []
        while time.monotonic() < end and not got:
            got = [s for s in self.plan.take(N=10) if s is not None]
            time.sleep(0.05)
        return got


@pytest.mark.slow
@pytest.mark.timeout(180)
def test_the_node_plans_on_dds_and_survives_bad_messages(maps_dir: Path, tmp_path: Path, student: tuple[Path, Path],
                                                         monkeypatch: pytest.MonkeyPatch) -> None:
    pytest.importorskip("cyclonedds")
    pytest.importorskip("onnxruntime")
    env = loopback_env(tmp_path)
    monkeypatch.setenv("CYCLONEDDS_URI", env["CYCLONEDDS_URI"])  # this process's participant: loopback too
    from spade.maps import load_ros_map
    from spade.ros.convert import quaternion_to_yaw

    onnx = student[1]
    m = load_ros_map(maps_dir.joinpath(*MAP))
    domain = unique_domain()
    log = tmp_path / "node.log"
    with open(log, "w") as out:
        node = subprocess.Popen([sys.executable, "-m", "spade.ros", f"model={onnx}", f"domain_id={domain}",
                                 f"record={tmp_path / 'session.mcap'}"],
                                cwd=tmp_path, env=env, stdout=out, stderr=subprocess.STDOUT)
    try:
        robot = Robot(domain)
        M = robot.M
        robot.map.write(M.occupancy_grid(m, "map"))
        robot.pose.write(M.pose_with_covariance(POSE, "map"))
        robot.wait_matched(90, node)
        wait_for(log, "robot pose received", 30)  # the latched map and pose reached the node
        sent = time.time_ns()
        robot.goal.write(M.pose_stamped(GOAL, "map"))
        paths = robot.paths(30)
        assert len(paths) == 1, log.read_text()
        path = paths[0]

        # The path: in the map frame, stamped, from the robot to the goal, connected and collision-free on the map.
        assert path.header.frame_id == "map"
        stamp = path.header.stamp.sec * 10**9 + path.header.stamp.nanosec
        assert sent - 10**9 < stamp < time.time_ns() + 10**9
        assert all(p.header.frame_id == "map" and (p.header.stamp.sec, p.header.stamp.nanosec) ==
                   (path.header.stamp.sec, path.header.stamp.nanosec) for p in path.poses)
        xy = np.array([[p.pose.position.x, p.pose.position.y] for p in path.poses])
        assert len(xy) == 64
        np.testing.assert_allclose(xy[0], POSE[:2], atol=1e-6)
        np.testing.assert_allclose(xy[-1], GOAL[:2], atol=1e-6)
        steps = np.linalg.norm(np.diff(xy, axis=0), axis=1)
        straight = float(np.linalg.norm(np.subtract(GOAL[:2], POSE[:2])))
        assert steps.max() < 0.1 and steps.sum() < 2 * straight, steps  # connected: evenly spaced, no jump
        assert free_along(m, xy), "the path crosses a cell that is not free on the map"
        q = path.poses[-1].pose.orientation
        assert quaternion_to_yaw(q.x, q.y, q.z, q.w) == pytest.approx(GOAL[2])  # the goal's heading at the end
        confidence = robot.confidence.take(N=10)
        assert confidence and 0.0 <= confidence[-1].data <= 1.0

        # A malformed map (sizes that disagree), then a goal off the map: logged, survived, no path published.
        bad = M.occupancy_grid(m, "map")
        bad.data = bad.data[:-5]
        robot.map.write(bad)
        wait_for(log, "malformed map ignored (keeping the previous one)", 20)
        robot.goal.write(M.pose_stamped((50.0, 50.0, 0.0), "map"))
        wait_for(log, "goal_outside_map", 20)
        assert not robot.paths(1.0), "a path was published for a goal off the map"
        assert node.poll() is None, "the node died"

        # Still planning on the good map: a new goal gets a path.
        robot.goal.write(M.pose_stamped(GOAL, "map"))
        assert len(robot.paths(30)) == 1
    finally:
        node.send_signal(signal.SIGINT)
        try:
            node.wait(30)
        except subprocess.TimeoutExpired:
            node.kill()
            node.wait()
    out = log.read_text()
    assert node.returncode == 0, out
    assert "Traceback" not in out, out
    assert "spade.ros node stopped" in out and "'plan': 2" in out and "'malformed': 1" in out, out

    # The session's recording: what the node took and published, as ROS 2 messages (mcap-ros2-support decodes it).
    mcap_ros2 = pytest.importorskip("mcap_ros2.reader")
    recorded = [(r.channel.topic, r.ros_msg) for r in mcap_ros2.read_ros2_messages(str(tmp_path / "session.mcap"))]
    topics = [t for t, _ in recorded]
    assert topics.count("/map") == 2 and topics.count("/goal_pose") == 3 and topics.count("/plan") == 2
    assert topics.count("/amcl_pose") == 1 and topics.count("/plan_confidence") == 2
    plans = [msg for t, msg in recorded if t == "/plan"]
    np.testing.assert_allclose([[p.pose.position.x, p.pose.position.y] for p in plans[0].poses], xy)

    # Replayed offline through the planner (python -m spade.ros replay=...): the same plans, no DDS.
    run = subprocess.run([sys.executable, "-m", "spade.ros", f"model={onnx}", f"replay={tmp_path / 'session.mcap'}",
                          f"replay_out={tmp_path / 'replayed'}"], cwd=tmp_path, env=env, capture_output=True,
                         text=True, timeout=120)
    assert run.returncode == 0, run.stdout + run.stderr
    assert "malformed map ignored" in run.stdout and "goal_outside_map" in run.stdout
    replayed = [r.ros_msg for r in mcap_ros2.read_ros2_messages(str(next((tmp_path / "replayed").glob("*.mcap"))))
                if r.channel.topic == "/plan"]
    assert len(replayed) == 2
    for a, b in zip(plans, replayed):
        np.testing.assert_allclose([[p.pose.position.x, p.pose.position.y] for p in a.poses],
                                   [[p.pose.position.x, p.pose.position.y] for p in b.poses], atol=1e-9)


@pytest.mark.parametrize("args, message", [
    (["model=/nonexistent/student.onnx"], "error: model /nonexistent/student.onnx does not exist"),
    (["model_path=null"], "error: model_path: no model; pass model=PATH"),
])
def test_the_node_refuses_bad_options_in_one_line(tmp_path: Path, args: list[str], message: str) -> None:
    run = subprocess.run([sys.executable, "-m", "spade.ros", *args], cwd=tmp_path, env=loopback_env(tmp_path),
                         capture_output=True, text=True, timeout=60)
    assert run.returncode == 2, run.stderr
    assert run.stderr.startswith(message) and "Traceback" not in run.stderr
    assert not (tmp_path / "home" / "logs" / "runs" / "ros").exists() or \
        not any((tmp_path / "home" / "logs" / "runs" / "ros").iterdir())  # a refused run leaves no run folder
