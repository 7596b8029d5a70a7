"""spade.ros without a network: OccupancyGrid <-> OccupancyMap, poses, paths as ROS 2 messages (byte for byte what
ROS 2's own CDR gives), and the node's logic (when it plans, what it logs and survives) with a stand-in planner."""

from __future__ import annotations

import logging
import math
from types import SimpleNamespace as NS

import numpy as np
import pytest

from spade.maps import FREE, OCCUPIED, UNKNOWN, OccupancyMap, generate_map
from spade.ros.convert import (MessageError, grid_fields, grid_to_map, path_yaws, pose_from_msg, quaternion_to_yaw,
                               split_stamp, yaw_to_quaternion)
from spade.ros.core import CoreSettings, PlannerCore, distance_to_polyline


# ------------------------------------------------------------------------------------------------ plain messages
def header(frame: str = "map") -> NS:
    return NS(stamp=NS(sec=1, nanosec=2), frame_id=frame)


def grid_msg(width: int, height: int, data, resolution: float = 0.05, origin=(1.0, -2.0), yaw: float = 0.0,
             frame: str = "map") -> NS:
    q = yaw_to_quaternion(yaw)
    pose = NS(position=NS(x=origin[0], y=origin[1], z=0.0), orientation=NS(x=q[0], y=q[1], z=q[2], w=q[3]))
    info = NS(map_load_time=NS(sec=0, nanosec=0), resolution=resolution, width=width, height=height, origin=pose)
    return NS(header=header(frame), info=info, data=data)


def pose_msg(x: float, y: float, yaw: float, frame: str = "map", covariance: bool = False) -> NS:
    q = yaw_to_quaternion(yaw)
    pose = NS(position=NS(x=x, y=y, z=0.0), orientation=NS(x=q[0], y=q[1], z=q[2], w=q[3]))
    return NS(header=header(frame), pose=NS(pose=pose, covariance=[0.0] * 36) if covariance else pose)


# ------------------------------------------------------------------------------------------------ conversions
def test_grid_rows_start_at_the_origin_and_values_become_codes() -> None:
    # 3 x 2 cells; the message's first row is the bottom of the map (y = origin), OccupancyMap's row 0 the top.
    m = grid_to_map(grid_msg(3, 2, [100, 0, -1, 0, 99, 0]))
    np.testing.assert_array_equal(m.grid, [[FREE, FREE, FREE], [OCCUPIED, FREE, UNKNOWN]])
    np.testing.assert_array_equal(m.costs, [[0, 99, 0], [100, 0, -1]])
    assert m.resolution == pytest.approx(0.05) and m.origin == (1.0, -2.0, 0.0) and m.name == "map"
    # The obstacle (data[0]) is the cell whose lower-left corner is the origin.
    np.testing.assert_allclose(m.pixel_to_world(np.array([0.0, 1.0])), [1.025, -1.975])
    # Nav2's lethal_cost_threshold: 99 (a costmap's inscribed cost) counts as an obstacle when asked.
    assert grid_to_map(grid_msg(3, 2, [100, 0, -1, 0, 99, 0]), lethal_threshold=99).grid[0, 1] == OCCUPIED


@pytest.mark.parametrize("with_costs", [False, True])
def test_map_to_grid_and_back_is_exact(with_costs: bool) -> None:
    m = generate_map("warehouse", 3)
    if with_costs:
        rng = np.random.default_rng(0)
        costs = rng.integers(-1, 101, size=m.grid.shape).astype(np.int8)
        m = OccupancyMap(np.where(costs < 0, UNKNOWN, np.where(costs >= 100, OCCUPIED, FREE)), m.resolution, m.origin,
                         costs=costs)
    f = grid_fields(m)
    back = grid_to_map(grid_msg(f.width, f.height, f.data.tolist(), f.resolution, f.origin[:2]))
    np.testing.assert_array_equal(back.grid, m.grid)
    assert back.origin == m.origin and back.resolution == m.resolution
    # rosbags hands data over as an int8 array; bytes work too.
    again = grid_to_map(grid_msg(f.width, f.height, f.data.tobytes(), f.resolution, f.origin[:2]))
    np.testing.assert_array_equal(again.grid, m.grid)


@pytest.mark.parametrize("msg, match", [
    (grid_msg(3, 2, [0] * 5), "5 values for 3 x 2"),
    (grid_msg(0, 2, []), "at least one cell"),
    (grid_msg(2, 2, [0] * 4, resolution=0.0), "resolution"),
    (grid_msg(2, 2, [0] * 4, resolution=float("nan")), "resolution"),
    (grid_msg(2, 2, [0] * 4, origin=(float("inf"), 0.0)), "origin"),
    (grid_msg(2, 2, [0] * 4, yaw=0.5), "origin yaw"),
    (grid_msg(2, 2, [0, 0, 101, 0]), "values from"),
    (grid_msg(2, 2, [0, -5, 0, 0]), "values from"),
    (NS(header=header(), data=[0]), "not an OccupancyGrid"),
])
def test_malformed_grids_are_message_errors(msg: NS, match: str) -> None:
    with pytest.raises(MessageError, match=match):
        grid_to_map(msg)


def test_poses_and_quaternions() -> None:
    for yaw in (0.0, 0.7, -2.5, math.pi):
        assert math.isclose(math.cos(quaternion_to_yaw(*yaw_to_quaternion(yaw)) - yaw), 1.0, abs_tol=1e-12)
    frame, pose = pose_from_msg(pose_msg(1.5, -2.0, 0.3, "odom"))
    assert frame == "odom"
    np.testing.assert_allclose(pose, [1.5, -2.0, 0.3])
    _, pose = pose_from_msg(pose_msg(1.5, -2.0, -1.2, covariance=True))  # PoseWithCovarianceStamped (AMCL)
    np.testing.assert_allclose(pose, [1.5, -2.0, -1.2])
    # A quaternion that is not unit length still gives its yaw (it is normalised).
    q = NS(x=0.0, y=0.0, z=2 * math.sin(0.25), w=2 * math.cos(0.25))
    assert pose_from_msg(NS(header=header(), pose=NS(position=NS(x=0, y=0, z=0), orientation=q)))[1][2] == \
        pytest.approx(0.5)
    bad = NS(header=header(), pose=NS(position=NS(x=0, y=0, z=0), orientation=NS(x=0, y=0, z=0, w=0)))
    with pytest.raises(MessageError, match="not a rotation"):
        pose_from_msg(bad)
    with pytest.raises(MessageError, match="not finite"):
        pose_from_msg(pose_msg(float("nan"), 0.0, 0.0))
    with pytest.raises(MessageError, match="not a pose"):
        pose_from_msg(NS(header=header()))


def test_path_yaws_point_along_the_path() -> None:
    pts = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 0.0], [1.0, 1.0]])
    np.testing.assert_allclose(path_yaws(pts), [0.0, 0.0, math.pi / 2, math.pi / 2])  # a repeated point keeps its yaw
    np.testing.assert_allclose(path_yaws(pts, goal_yaw=3.0)[-1], 3.0)
    assert split_stamp(1_500_000_000_123) == (1500, 123)


# ------------------------------------------------------------------------------------------------ DDS types
def test_dds_messages_are_ros2_cdr_byte_for_byte() -> None:
    """The DDS types serialise exactly as ROS 2's own CDR (rosbags' serialiser of the .msg definitions)."""
    M = pytest.importorskip("spade.ros.messages")
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    m = OccupancyMap(np.array([[1, 2, 0], [1, 1, 2]], np.uint8), 0.05, (1.0, -2.0, 0.0))
    cases = {
        "nav_msgs/msg/OccupancyGrid": M.occupancy_grid(m, "map", 5),
        "nav_msgs/msg/Path": M.path([[0.0, 0.0], [1.0, 0.5], [2.0, 0.5]], "map", 1_700_000_000_000_000_001, 0.2),
        "geometry_msgs/msg/PoseStamped": M.pose_stamped([1.0, 2.0, 0.5], "map", 7),
        "geometry_msgs/msg/PoseWithCovarianceStamped": M.pose_with_covariance([1.0, 2.0, -0.5], "map", 7,
                                                                               np.arange(36.0)),
        "std_msgs/msg/Float32": M.Float32(0.25),
    }
    for name, msg in cases.items():
        raw = bytes(msg.serialize())
        assert raw[:4] == b"\x00\x01\x00\x00", name  # CDR little endian, as ROS 2 writes it
        decoded = ts.deserialize_cdr(raw, name)
        assert bytes(ts.serialize_cdr(decoded, name)) == raw, name
        assert type(msg).__idl_typename__ == "{}::msg::dds_::{}_".format(*name.split("/msg/")).replace("/", "::")
    # The map survives the wire: DDS sample -> CDR -> sample -> OccupancyMap.
    grid = M.OccupancyGrid.deserialize(bytes(cases["nav_msgs/msg/OccupancyGrid"].serialize()))
    np.testing.assert_array_equal(grid_to_map(grid).grid, m.grid)
    path = ts.deserialize_cdr(bytes(cases["nav_msgs/msg/Path"].serialize()), "nav_msgs/msg/Path")
    assert path.header.frame_id == "map" and len(path.poses) == 3
    assert (path.header.stamp.sec, path.header.stamp.nanosec) == (1_700_000_000, 1)
    assert all(p.header.stamp.sec == 1_700_000_000 and p.header.frame_id == "map" for p in path.poses)
    last = path.poses[-1].pose.orientation
    assert quaternion_to_yaw(last.x, last.y, last.z, last.w) == pytest.approx(0.2)


# ------------------------------------------------------------------------------------------------ the node's logic
class FakePlanner:
    """Plans a straight line; fails with goal_outside_map off a 10 x 10 m map, like spade.planner.Planner."""

    def __init__(self) -> None:
        self.calls: list[tuple[np.ndarray, np.ndarray]] = []

    def plan(self, m: OccupancyMap, pose: np.ndarray, goal: np.ndarray, previous: np.ndarray | None = None) -> NS:
        self.calls.append((np.array(pose), np.array(goal)))
        if not (0 <= goal[0] <= 10 and 0 <= goal[1] <= 10):
            return NS(success=False, code="goal_outside_map", reason="goal lies outside map",
                      waypoints=np.zeros((0, 2)), subgoal=False, low_share=float("nan"))
        pts = np.linspace(pose[:2], goal, 10)
        return NS(success=True, code=None, reason=None, waypoints=pts, subgoal=False, low_share=0.0, fallback=False,
                  length_m=float(np.linalg.norm(goal - pose[:2])))


def empty_map_msg() -> NS:
    return grid_msg(100, 100, [0] * 10000, resolution=0.1, origin=(0.0, 0.0))


def test_the_core_plans_on_goals_and_when_the_robot_leaves_the_plan(caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.INFO, logger="spade.ros")
    now = [0.0]
    planner = FakePlanner()
    core = PlannerCore(planner, CoreSettings(min_replan_interval_s=0.0), clock=lambda: now[0], now_ns=lambda: 42)
    assert core.handle_goal(pose_msg(5.0, 5.0, 0.0)) is None  # no map, no pose yet: waits
    assert "waiting for a map and the robot's pose" in caplog.text
    assert core.handle_map(empty_map_msg()) is None
    event = core.handle_pose(pose_msg(1.0, 1.0, 0.0, covariance=True))  # the waiting goal is planned now
    assert event is not None and event.success and event.frame_id == "map" and event.stamp_ns == 42
    np.testing.assert_allclose(event.result.waypoints[-1], [5.0, 5.0])
    assert core.handle_pose(pose_msg(2.0, 2.1, 0.0)) is None  # on the plan (0.07 m off): no re-plan
    event = core.handle_pose(pose_msg(2.0, 3.0, 0.0))  # 0.7 m off the plan
    assert event is not None and event.trigger.startswith("off the plan")
    np.testing.assert_allclose(event.result.waypoints[0], [2.0, 3.0])
    assert core.handle_goal(pose_msg(8.0, 2.0, 1.0)).success  # a new goal: planned at once
    assert core.handle_pose(pose_msg(7.9, 2.05, 0.0)) is None and core.counts["reached"] == 1
    assert core.handle_pose(pose_msg(0.5, 0.5, 0.0)) is None  # no goal: nothing to plan
    assert core.counts["plan"] == 3 and len(planner.calls) == 3


def test_the_core_logs_and_survives_what_it_cannot_use(caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.INFO, logger="spade.ros")
    planner = FakePlanner()
    core = PlannerCore(planner, CoreSettings(min_replan_interval_s=0.0))
    core.handle_map(empty_map_msg())
    core.handle_pose(pose_msg(1.0, 1.0, 0.0, covariance=True))
    assert core.handle_map(grid_msg(10, 10, [0] * 7)) is None  # malformed: the previous map stays
    assert "malformed map ignored (keeping the previous one): data holds 7 values" in caplog.text
    assert core.state.map is not None and core.state.map.width == 100
    event = core.handle_goal(pose_msg(50.0, 50.0, 0.0))  # off the map: logged, no path, goal dropped
    assert event is not None and not event.success
    assert "no path (goal, " in caplog.text and "goal_outside_map" in caplog.text and "goal dropped" in caplog.text
    assert core.state.goal is None
    assert core.handle_goal(pose_msg(3.0, 3.0, 0.0, frame="odom")) is None  # another frame: no TF here
    assert "goal in frame 'odom' ignored" in caplog.text
    assert core.handle_goal(NS(header=header(), pose=NS())) is None
    assert core.handle_pose(NS()) is None
    assert "malformed goal ignored" in caplog.text and "malformed pose ignored" in caplog.text

    class Broken(FakePlanner):
        def plan(self, *args, **kwargs):  # noqa: ANN002, ANN003, ANN202
            raise RuntimeError("boom")

    core.planner = Broken()
    assert core.handle_goal(pose_msg(3.0, 3.0, 0.0)) is None
    assert "planning failed (goal): RuntimeError: boom" in caplog.text
    assert core.counts == {"map": 1, "pose": 1, "malformed": 3, "no_path": 2, "wrong_frame": 1, "goal": 2}


def test_distance_to_polyline() -> None:
    line = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 2.0]])
    assert distance_to_polyline(np.array([1.0, 0.5]), line) == pytest.approx(0.5)
    assert distance_to_polyline(np.array([3.0, 3.0]), line) == pytest.approx(math.sqrt(2))
    assert distance_to_polyline(np.array([0.0, 0.0]), np.zeros((0, 2))) == math.inf
