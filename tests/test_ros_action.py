"""The ComputePathToPose action server without a network: its DDS types against CDR bytes written by hand from the
documented message definitions (nav2_msgs Humble / Iron / Jazzy, action_msgs, unique_identifier_msgs) and
rmw_cyclonedds' service header; the goal logic (accept, plan, error codes, wait, cancel, get_result) with a stand-in
planner; the node's options typed before any work; the deferred re-plan; the map bound."""

from __future__ import annotations

import logging
import struct
from types import SimpleNamespace as NS

import numpy as np
import pytest

pytest.importorskip("cyclonedds")

from spade.ros import messages as M  # noqa: E402
from spade.ros.action import ActionSettings, GoalLogic  # noqa: E402
from spade.ros.action_types import CANCEL, ERROR, STATUS, action_topics, types_for  # noqa: E402
from spade.ros.convert import yaw_to_quaternion  # noqa: E402
from spade.ros.core import CoreSettings, PlannerCore  # noqa: E402


# ------------------------------------------------------------------------------------------------ hand-written CDR
class CDR:
    """Plain CDR (XCDR1), little endian, as ROS 2 writes it: a 4-byte encapsulation header (0x00 0x01 0x00 0x00),
    each primitive aligned to its size counted from after that header, strings as uint32 length (with the NUL),
    bytes, NUL; sequences as uint32 count then the elements."""

    def __init__(self) -> None:
        self.body = bytearray()

    def align(self, n: int) -> None:
        self.body += b"\0" * (-len(self.body) % n)

    def put(self, fmt: str, value) -> CDR:  # noqa: ANN001
        size = struct.calcsize(fmt)
        self.align(size)
        self.body += struct.pack("<" + fmt, value)
        return self

    def string(self, s: str) -> CDR:
        raw = s.encode() + b"\0"
        self.put("I", len(raw))
        self.body += raw
        return self

    def time(self, sec: int, nanosec: int) -> CDR:
        return self.put("i", sec).put("I", nanosec)

    def pose_stamped(self, sec: int, nanosec: int, frame: str, x: float, y: float, yaw: float) -> CDR:
        self.time(sec, nanosec).string(frame)
        for v in (x, y, 0.0, *yaw_to_quaternion(yaw)):
            self.put("d", v)
        return self

    def bytes(self) -> bytes:
        return b"\x00\x01\x00\x00" + bytes(self.body)


GID = bytes(range(1, 17))


def test_action_topic_and_type_names_are_ros2s() -> None:
    t = action_topics("/compute_path_to_pose")
    assert t["send_goal_request"] == "rq/compute_path_to_pose/_action/send_goalRequest"
    assert t["get_result_reply"] == "rr/compute_path_to_pose/_action/get_resultReply"
    assert t["cancel_request"] == "rq/compute_path_to_pose/_action/cancel_goalRequest"
    assert t["status"] == "rt/compute_path_to_pose/_action/status"
    assert t["feedback"] == "rt/compute_path_to_pose/_action/feedback"
    assert action_topics("spade/plan_to")["send_goal_reply"] == "rr/spade/plan_to/_action/send_goalReply"
    T = types_for("jazzy")
    assert T.SendGoalRequest.__idl_typename__ == "nav2_msgs::action::dds_::ComputePathToPose_SendGoal_Request_"
    assert T.GetResultResponse.__idl_typename__ == "nav2_msgs::action::dds_::ComputePathToPose_GetResult_Response_"
    assert T.CancelGoalRequest.__idl_typename__ == "action_msgs::srv::dds_::CancelGoal_Request_"
    assert T.GoalStatusArray.__idl_typename__ == "action_msgs::msg::dds_::GoalStatusArray_"
    assert T.FeedbackMessage.__idl_typename__ == "nav2_msgs::action::dds_::ComputePathToPose_FeedbackMessage_"
    with pytest.raises(ValueError, match="foxy"):
        types_for("foxy")


@pytest.mark.parametrize("distro", ["humble", "iron", "jazzy"])
def test_send_goal_request_bytes(distro: str) -> None:
    T = types_for(distro)
    req = T.SendGoalRequest(0x1122334455667788, 7, T.UUID(list(GID)), T.Goal(
        M.PoseStamped(M.Header(M.Time(3, 4), "map"), M.pose(1.5, -2.0, 0.5)),
        M.PoseStamped(M.Header(M.Time(0, 0), "map"), M.pose(0.25, 0.5, -1.0)), "GridBased", True))
    cdr = CDR().put("Q", 0x1122334455667788).put("q", 7)  # rmw_cyclonedds: uint64 guid, int64 seq
    cdr.body += GID  # unique_identifier_msgs/UUID: uint8[16]
    cdr.pose_stamped(3, 4, "map", 1.5, -2.0, 0.5).pose_stamped(0, 0, "map", 0.25, 0.5, -1.0)
    cdr.string("GridBased").put("?", True)
    assert req.serialize() == cdr.bytes()
    back = T.SendGoalRequest.deserialize(cdr.bytes())
    assert bytes(back.goal_id.uuid) == GID and back.goal == req.goal and back.client_guid == req.client_guid


def test_result_layouts_differ_by_distribution() -> None:
    path = M.path(np.array([[0.0, 0.0], [1.0, 0.0]]), "map", 5_000_000_001, 0.0)

    def expected(distro: str) -> bytes:
        cdr = CDR().put("Q", 9).put("q", 2).put("b", STATUS.ABORTED)
        cdr.time(5, 1).string("map").put("I", 2)  # nav_msgs/Path: header, poses
        for x in (0.0, 1.0):
            cdr.pose_stamped(5, 1, "map", x, 0.0, 0.0)
        cdr.time(0, 250_000_000)  # builtin_interfaces/Duration planning_time
        if distro in ("iron", "jazzy"):
            cdr.put("H", ERROR.GOAL_OCCUPIED)  # uint16 error_code
        if distro == "jazzy":
            cdr.string("goal on an obstacle")  # string error_msg
        return cdr.bytes()

    sizes = {}
    for distro in ("humble", "iron", "jazzy"):
        T = types_for(distro)
        kwargs = {"path": path, "planning_time": T.Duration(0, 250_000_000)}
        if T.has_error_code:
            kwargs["error_code"] = ERROR.GOAL_OCCUPIED
        if T.has_error_msg:
            kwargs["error_msg"] = "goal on an obstacle"
        raw = T.GetResultResponse(9, 2, STATUS.ABORTED, T.Result(**kwargs)).serialize()
        assert raw == expected(distro), distro
        sizes[distro] = len(raw)
    assert sizes["humble"] < sizes["iron"] < sizes["jazzy"]


def test_cancel_status_and_feedback_bytes() -> None:
    T = types_for("jazzy")
    req = T.CancelGoalRequest(1, 3, T.GoalInfo(T.UUID(list(GID)), M.Time(0, 0)))
    cdr = CDR().put("Q", 1).put("q", 3)
    cdr.body += GID
    assert req.serialize() == cdr.time(0, 0).bytes()
    resp = T.CancelGoalResponse(1, 3, CANCEL.ERROR_NONE, [T.GoalInfo(T.UUID(list(GID)), M.Time(7, 8))])
    cdr = CDR().put("Q", 1).put("q", 3).put("b", 0).put("I", 1)
    cdr.body += GID
    assert resp.serialize() == cdr.time(7, 8).bytes()
    status = T.GoalStatusArray([T.GoalStatus(T.GoalInfo(T.UUID(list(GID)), M.Time(7, 8)), STATUS.SUCCEEDED)])
    cdr = CDR().put("I", 1)
    cdr.body += GID
    assert status.serialize() == cdr.time(7, 8).put("b", 4).bytes()
    feedback = T.FeedbackMessage(T.UUID(list(GID)))
    cdr = CDR()
    cdr.body += GID
    assert feedback.serialize() == cdr.put("B", 0).bytes()  # an empty message's structure_needs_at_least_one_member


# ------------------------------------------------------------------------------------------------ the goal logic
class FakePlanner:
    """Free 10 x 10 m; (5, 5) is an obstacle; a straight path otherwise."""

    resolution = 0.1

    def plan(self, m, pose, goal, previous=None):  # noqa: ANN001, ANN201
        if not (0 <= goal[0] <= 10 and 0 <= goal[1] <= 10):
            return NS(success=False, code="goal_outside_map", reason="outside", waypoints=np.zeros((0, 2)))
        if not (0 <= pose[0] <= 10 and 0 <= pose[1] <= 10):
            return NS(success=False, code="start_outside_map", reason="outside", waypoints=np.zeros((0, 2)))
        if np.allclose(goal, [5.0, 5.0]):
            return NS(success=False, code="goal_not_free", reason="obstacle", waypoints=np.zeros((0, 2)))
        if np.allclose(goal, [9.0, 9.0]):
            return NS(success=False, code="no_free_path", reason="walled in", waypoints=np.zeros((0, 2)))
        pts = np.linspace(pose[:2], goal, 8)
        return NS(success=True, code=None, waypoints=pts, subgoal=False, low_share=0.0, fallback=False,
                  length_m=float(np.linalg.norm(goal - pose[:2])))


def grid(width: int = 100, height: int = 100, resolution: float = 0.1) -> NS:
    pose = NS(position=NS(x=0.0, y=0.0, z=0.0), orientation=NS(x=0.0, y=0.0, z=0.0, w=1.0))
    info = NS(map_load_time=NS(sec=0, nanosec=0), resolution=resolution, width=width, height=height, origin=pose)
    return NS(header=NS(stamp=NS(sec=1, nanosec=0), frame_id="map"), info=info, data=[0] * (width * height))


def make_logic(distro: str = "jazzy", **settings) -> tuple[GoalLogic, PlannerCore, list[float], list]:  # noqa: ANN003
    now = [0.0]
    core = PlannerCore(FakePlanner(), CoreSettings(), clock=lambda: now[0], now_ns=lambda: 10**9)
    published: list = []
    logic = GoalLogic(core, ActionSettings(enabled=True, distro=distro, **settings), clock=lambda: now[0],
                      now_ns=lambda: 2 * 10**9, on_path=lambda path, event: published.append(path))
    return logic, core, now, published


def send(logic: GoalLogic, gid: bytes, goal, start=None, frame: str = "map", planner_id: str = "", seq: int = 1):  # noqa: ANN001, ANN201
    T = logic.T
    g = T.Goal(M.pose_stamped(goal, frame, 0), M.pose_stamped(start or (0, 0, 0), frame, 0), planner_id,
               start is not None)
    return logic.send_goal(T.SendGoalRequest(5, seq, T.UUID(list(gid)), g))


def result_of(logic: GoalLogic, gid: bytes, seq: int = 100):  # noqa: ANN201
    return logic.get_result(logic.T.GetResultRequest(5, seq, logic.T.UUID(list(gid))))


def gid(n: int) -> bytes:
    return bytes([n] * 16)


def test_goals_get_paths_and_the_error_codes_of_their_failures() -> None:
    logic, core, now, published = make_logic()
    core.handle_map(grid())
    reply = send(logic, gid(1), (8.0, 2.0, 1.0), start=(1.0, 1.0, 0.0))
    assert reply.accepted and reply.client_guid == 5 and reply.sequence_number == 1 and reply.stamp.sec == 2
    assert result_of(logic, gid(1)) is None  # not planned yet: answered later
    replies = logic.step()
    assert len(replies) == 1 and replies[0].status == STATUS.SUCCEEDED and replies[0].sequence_number == 100
    res = replies[0].result
    assert res.error_code == ERROR.NONE and res.error_msg == "" and res.path.header.frame_id == "map"
    xy = np.array([[p.pose.position.x, p.pose.position.y] for p in res.path.poses])
    np.testing.assert_allclose(xy[[0, -1]], [[1.0, 1.0], [8.0, 2.0]])
    assert len(published) == 1  # also on the plan topic, as planner_server publishes its own
    cases = {2: ((5.0, 5.0, 0.0), (1.0, 1.0, 0.0), ERROR.GOAL_OCCUPIED),
             3: ((50.0, 5.0, 0.0), (1.0, 1.0, 0.0), ERROR.GOAL_OUTSIDE_MAP),
             4: ((2.0, 2.0, 0.0), (-3.0, 1.0, 0.0), ERROR.START_OUTSIDE_MAP),
             5: ((9.0, 9.0, 0.0), (1.0, 1.0, 0.0), ERROR.NO_VALID_PATH)}
    for n, (goal, start, _) in cases.items():
        assert send(logic, gid(n), goal, start=start, seq=n).accepted
    logic.step()
    for n, (_, _, code) in cases.items():
        reply = result_of(logic, gid(n), seq=200 + n)
        assert reply.status == STATUS.ABORTED and reply.result.error_code == code, n
        assert reply.result.error_msg and not reply.result.path.poses
    assert result_of(logic, gid(99)).status == STATUS.UNKNOWN  # an unknown goal id
    assert not send(logic, gid(1), (1.0, 1.0, 0.0)).accepted  # an id in use
    statuses = {bytes(s.goal_info.goal_id.uuid): s.status for s in logic.status_array().status_list}
    assert statuses[gid(1)] == STATUS.SUCCEEDED and statuses[gid(2)] == STATUS.ABORTED


def test_humble_has_no_error_code_its_aborted_status_says_it() -> None:
    logic, core, _, _ = make_logic("humble")
    core.handle_map(grid())
    send(logic, gid(1), (5.0, 5.0, 0.0), start=(1.0, 1.0, 0.0))
    logic.step()
    reply = result_of(logic, gid(1))
    assert reply.status == STATUS.ABORTED and not hasattr(reply.result, "error_code")


def test_a_goal_waits_for_the_pose_can_be_canceled_or_times_out() -> None:
    logic, core, now, _ = make_logic(wait_s=5.0)
    send(logic, gid(1), (3.0, 3.0, 0.0))  # use_start false, no map, no pose yet
    send(logic, gid(2), (3.0, 3.0, 0.0), seq=2)
    logic.step()
    assert result_of(logic, gid(1)) is None
    T = logic.T
    cancel = logic.cancel(T.CancelGoalRequest(5, 3, T.GoalInfo(T.UUID(list(gid(1))), M.Time(0, 0))))
    assert cancel.return_code == CANCEL.ERROR_NONE and [bytes(g.goal_id.uuid) for g in cancel.goals_canceling] == [gid(1)]
    logic.step()
    assert result_of(logic, gid(1)).status == STATUS.CANCELED
    again = logic.cancel(T.CancelGoalRequest(5, 4, T.GoalInfo(T.UUID(list(gid(1))), M.Time(0, 0))))
    assert again.return_code == CANCEL.ERROR_GOAL_TERMINATED and not again.goals_canceling
    unknown = logic.cancel(T.CancelGoalRequest(5, 5, T.GoalInfo(T.UUID(list(gid(9))), M.Time(0, 0))))
    assert unknown.return_code == CANCEL.ERROR_UNKNOWN_GOAL_ID
    now[0] = 6.0
    logic.step()
    reply = result_of(logic, gid(2))
    assert reply.status == STATUS.ABORTED and reply.result.error_code == ERROR.TIMEOUT and "no map" in reply.result.error_msg
    core.handle_map(grid())
    send(logic, gid(3), (3.0, 3.0, 0.0), seq=6)  # a map, but no robot pose: Nav2 would fail its TF lookup
    now[0] = 12.0
    logic.step()
    assert result_of(logic, gid(3)).result.error_code == ERROR.TF_ERROR
    core.handle_pose(M.pose_with_covariance((1.0, 1.0, 0.0), "map", 0))
    send(logic, gid(4), (3.0, 3.0, 0.0), seq=7)  # now from the robot's latest pose
    logic.step()
    reply = result_of(logic, gid(4))
    assert reply.status == STATUS.SUCCEEDED and reply.result.path.poses[0].pose.position.x == pytest.approx(1.0)
    send(logic, gid(5), (3.0, 3.0, 0.0), seq=8)
    cancel_all = logic.cancel(T.CancelGoalRequest(5, 9, T.GoalInfo(T.UUID([0] * 16), M.Time(0, 0))))
    assert [bytes(g.goal_id.uuid) for g in cancel_all.goals_canceling] == [gid(5)]  # only the active one
    now[0] = 12.0 + 901.0
    logic.step()
    assert not logic.goals  # done goals expire after result_timeout_s


def test_frames_planner_ids_and_slow_plans_are_errors() -> None:
    logic, core, now, _ = make_logic(planner_ids=("SPADE",))
    core.handle_map(grid())
    send(logic, gid(1), (3.0, 3.0, 0.0), start=(1.0, 1.0, 0.0), frame="odom")
    send(logic, gid(2), (3.0, 3.0, 0.0), start=(1.0, 1.0, 0.0), planner_id="GridBased", seq=2)
    send(logic, gid(3), (3.0, 3.0, 0.0), start=(1.0, 1.0, 0.0), planner_id="SPADE", seq=3)
    logic.step()
    assert result_of(logic, gid(1)).result.error_code == ERROR.TF_ERROR
    assert result_of(logic, gid(2)).result.error_code == ERROR.INVALID_PLANNER
    assert result_of(logic, gid(3)).status == STATUS.SUCCEEDED
    slow, core, _, _ = make_logic(timeout_s=0.001)
    core.handle_map(grid())

    class Slow(FakePlanner):
        def plan(self, *a, **kw):  # noqa: ANN002, ANN003, ANN202
            import time

            time.sleep(0.01)
            return super().plan(*a, **kw)

    core.planner = Slow()
    send(slow, gid(1), (3.0, 3.0, 0.0), start=(1.0, 1.0, 0.0))
    slow.step()
    assert result_of(slow, gid(1)).result.error_code == ERROR.TIMEOUT


# ------------------------------------------------------------------------------------------------ the node's core
def test_an_off_plan_pose_inside_the_interval_replans_once_it_has_passed() -> None:
    now = [0.0]
    core = PlannerCore(FakePlanner(), CoreSettings(min_replan_interval_s=0.5), clock=lambda: now[0])
    core.handle_map(grid())
    core.handle_pose(M.pose_with_covariance((1.0, 1.0, 0.0), "map", 0))
    assert core.handle_goal(M.pose_stamped((8.0, 1.0, 0.0), "map", 0)).success
    now[0] = 0.03
    assert core.handle_pose(M.pose_with_covariance((3.0, 2.1, 0.0), "map", 0)) is None  # 1.1 m off, 30 ms after
    assert core.tick() is None  # still inside the interval
    now[0] = 0.6  # no new pose (the robot stands still), yet the interval has passed: plan now
    event = core.tick()
    assert event is not None and event.success and event.trigger.startswith("off the plan by 1.10 m")
    np.testing.assert_allclose(event.result.waypoints[0], [3.0, 2.1])
    assert core.tick() is None  # once


def test_a_map_too_big_for_the_students_resolution_is_refused_at_once(caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.INFO, logger="spade.ros")
    core = PlannerCore(FakePlanner(), CoreSettings())
    huge = grid(1000, 1000, 5.0)
    import time

    t0 = time.perf_counter()
    assert core.handle_map(huge) is None
    assert time.perf_counter() - t0 < 1.0
    assert core.state.map is None and core.counts == {"too_big": 1}
    assert "50,000 x 50,000 cells" in caplog.text and "node.max_map_cells" in caplog.text
    assert PlannerCore(FakePlanner(), CoreSettings(max_map_cells=10**10)).map_too_big(huge) is None


@pytest.mark.parametrize("kwargs, match", [
    ({"replan_distance_m": "abc"}, r"node.replan_distance_m='abc': a number; pass e.g. node.replan_distance_m=0.5"),
    ({"replan_on_map": "maybe"}, r"node.replan_on_map='maybe': a boolean"),
    ({"goal_reached_m": -1.0}, r"node.goal_reached_m=-1.0: must be > 0"),
    ({"lethal_threshold": 101}, r"node.lethal_threshold=101: must be <= 100"),
    ({"min_replan_interval_s": float("nan")}, r"a finite number"),
])
def test_node_settings_are_typed_and_ranged(kwargs: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        CoreSettings(**kwargs)


def test_qos_overrides_are_checked() -> None:
    from spade.ros.node_options import check_qos

    assert check_qos({"map": {"reliability": "best_effort", "durability": None, "depth": None}, "pose": None}) == {
        "map": {"reliability": "best_effort"}}
    for bad, match in (({"map": {"reliability": "banana"}}, "qos.map.reliability='banana': use reliable or best_effort"),
                       ({"map": {"durability": "forever"}}, "use volatile or transient_local"),
                       ({"plan": {"depth": 0}}, "a positive integer"), ({"odom": {}}, "qos.odom: no such topic"),
                       ({"map": {"history": "all"}}, "qos.map.history: no such QoS setting")):
        with pytest.raises(ValueError, match=match):
            check_qos(bad)


def test_the_docs_qos_override_composes_and_bad_options_are_refused_before_any_work() -> None:
    """The QoS override exactly as docs/deployment.md writes it composes; bad values stop python -m spade.ros
    with one line before the model is looked at (a missing model would be the error otherwise)."""
    import re
    from pathlib import Path

    from hydra import compose, initialize_config_dir

    from spade.paths import CONF_DIR
    from spade.ros.launch import checked_options
    from spade.utils.errors import ConfigError

    docs = (Path(__file__).resolve().parents[1] / "docs" / "deployment.md").read_text()
    literal = re.search(r"`'(qos=\{map: [^`]*\})'`", docs)
    assert literal, "docs/deployment.md no longer shows the QoS override"
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        cfg = compose("ros", overrides=[literal.group(1)])
        assert checked_options(cfg)["qos"] == {"map": {"reliability": "best_effort", "durability": "volatile"}}
        cfg = compose("ros", overrides=["qos.plan.depth=5"])
        assert checked_options(cfg)["qos"] == {"plan": {"depth": 5}}
        for override, match in (("node.replan_distance_m=abc", "node.replan_distance_m='abc'"),
                                ("qos.map.reliability=banana", "banana"), ("action.enabled=maybe", "action.enabled"),
                                ("action.distro=foxy", "action.distro='foxy'"), ("action.timeout_s=0", "must be > 0"),
                                ("pose_type=odom", "pose_type='odom'"), ("foxglove_port=99999", "foxglove_port")):
            cfg = compose("ros", overrides=[override])
            with pytest.raises(ConfigError, match=re.escape(match)):
                checked_options(cfg)
                from spade.ros.launch import foxglove_options

                foxglove_options(cfg)


def test_an_accepted_action_goal_is_shown_as_a_goal() -> None:
    """With the action (Nav2's bt_navigator) no /goal_pose arrives: the node hands each accepted goal's pose to its
    viewers (the live Foxglove server's /goal_pose) through on_goal."""
    now = [0.0]
    core = PlannerCore(FakePlanner(), CoreSettings(), clock=lambda: now[0], now_ns=lambda: 10**9)
    shown: list = []
    logic = GoalLogic(core, ActionSettings(enabled=True), clock=lambda: now[0], now_ns=lambda: 2 * 10**9,
                      on_goal=shown.append)
    core.handle_map(grid())
    assert send(logic, gid(1), (8.0, 2.0, 1.0), start=(1.0, 1.0, 0.0)).accepted
    assert not send(logic, gid(1), (3.0, 3.0, 0.0)).accepted  # a rejected goal is not shown
    assert len(shown) == 1 and (shown[0].pose.position.x, shown[0].pose.position.y) == (8.0, 2.0)
    assert shown[0].header.frame_id == "map"
