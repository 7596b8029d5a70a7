"""A ``nav2_msgs/action/ComputePathToPose`` action server (Nav2's planner server interface) and a client, on DDS.

Nav2's ``bt_navigator`` asks its planner for a path through this action (the behaviour tree's ``ComputePathToPose``
node, ``server_name`` ``compute_path_to_pose`` by default). :class:`ActionServer` answers it with the node's
planner, so that SPADE can replace ``planner_server`` (same action name) or run beside it under another name (one
attribute of the behaviour tree; ``docs/deployment.md``). The wire layout is :mod:`spade.ros.action_types`.

What a goal gets (:class:`GoalLogic`, transport-free, so the tests drive it without DDS):

- accepted at once (``send_goal``), then EXECUTING; planned from ``start`` when ``use_start`` is true, else from the
  robot's latest pose (the node's pose topic), on the node's latest map, to ``goal``;
- a goal that arrives before the map (or, with ``use_start`` false, before a pose) waits up to ``wait_s``: then it
  is ABORTED with TIMEOUT (no map) or TF_ERROR (no robot pose: Nav2 reads it from TF); a waiting goal can be
  canceled (CANCELED);
- SUCCEEDED with the path (frame of the map, stamped, oriented; the last pose at the goal's yaw) and
  ``planning_time``; or ABORTED with the error code of the failure: START_OUTSIDE_MAP, GOAL_OUTSIDE_MAP,
  START_OCCUPIED, GOAL_OCCUPIED, NO_VALID_PATH (no path, a goal beyond the window with ``far_goal: fail``),
  TIMEOUT (planning took longer than ``timeout_s``), TF_ERROR (a start or goal in another frame than the map's: the
  node has no TF), INVALID_PLANNER (``planner_id`` not in ``planner_ids``, when that list is set), UNKNOWN (the
  planner raised). Humble's result has no error code: there the ABORTED status alone says it failed.
- ``get_result`` answers when the goal is done (at once when it already is; an unknown goal id gets status
  UNKNOWN); ``cancel_goal`` follows ``action_msgs/srv/CancelGoal`` (one goal, all goals, or all before a stamp);
  the status topic (transient-local) lists every goal of the last ``result_timeout_s`` seconds.

Planning runs in the node's thread (one plan takes tens of milliseconds): goals are served in order.
"""

from __future__ import annotations

import logging
import math
import time
import uuid as uuid_module
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from spade.ros import messages as M
from spade.ros.action_types import CANCEL, ERROR, STATUS, action_topics, types_for
from spade.ros.convert import MessageError, nanoseconds, pose_from_msg, split_stamp
from spade.ros.dds import make_qos

__all__ = ["ActionClient", "ActionServer", "ActionSettings", "GoalLogic", "PLANNER_ERRORS"]

log = logging.getLogger("spade.ros")

# spade.planner failure codes -> ComputePathToPose error codes
PLANNER_ERRORS = {
    "start_outside_map": ERROR.START_OUTSIDE_MAP, "goal_outside_map": ERROR.GOAL_OUTSIDE_MAP,
    "start_not_free": ERROR.START_OCCUPIED, "goal_not_free": ERROR.GOAL_OCCUPIED,
}
TERMINAL = (STATUS.SUCCEEDED, STATUS.CANCELED, STATUS.ABORTED)


@dataclass(frozen=True)
class ActionSettings:
    """``conf/ros.yaml``'s ``action`` block."""

    enabled: bool = False
    name: str = "/compute_path_to_pose"   # Nav2's planner_server's action; another name runs beside it
    distro: str = "jazzy"                 # the result layout: humble | iron | jazzy (jazzy: also later ones)
    wait_s: float = 5.0                   # a goal before the map / the robot's pose waits this long
    timeout_s: float = 2.0                # a plan that takes longer is ABORTED with TIMEOUT
    result_timeout_s: float = 900.0       # done goals stay in the status list and get_result this long (rcl's)
    planner_ids: tuple[str, ...] = ()     # accepted planner_id values ('' always); empty: any


@dataclass
class _Goal:
    goal_id: bytes
    request: Any
    accepted_ns: int
    accepted_t: float
    status: int = STATUS.EXECUTING
    result: Any = None
    done_t: float = math.inf
    waiting_replies: list[tuple[int, int]] = field(default_factory=list)  # get_result requests to answer


def _uuid(value: Any) -> bytes:
    return bytes(int(v) & 0xFF for v in value.uuid)


class GoalLogic:
    """The action server without DDS: requests in, replies and status out (see the module docstring).

    ``core``: the node's :class:`spade.ros.core.PlannerCore` (its map, pose, frame and planner); ``clock``:
    monotonic seconds; ``now_ns``: wall-clock nanoseconds (stamps); ``on_path``: called with each successful
    ``nav_msgs/Path`` (the node also publishes it on its plan topic, as ``planner_server`` does); ``on_goal``: called
    with each accepted goal's ``PoseStamped`` (the node shows it to its viewers as a ``/goal_pose`` goal).
    """

    def __init__(self, core: Any, settings: ActionSettings | None = None, *,
                 clock: Callable[[], float] = time.monotonic, now_ns: Callable[[], int] = time.time_ns,
                 on_path: Callable[[Any, Any], None] | None = None,
                 on_goal: Callable[[Any], None] | None = None) -> None:
        self.core = core
        self.settings = settings or ActionSettings()
        self.T = types_for(self.settings.distro)
        self.clock, self.now_ns = clock, now_ns
        self.on_path = on_path
        self.on_goal = on_goal
        self.goals: dict[bytes, _Goal] = {}
        self.status_changed = False

    # -- services ----------------------------------------------------------------------------------------------
    def send_goal(self, req: Any) -> Any:
        """``send_goal``: accept (every well-formed goal; a duplicate id is rejected), reply at once."""
        gid = _uuid(req.goal_id)
        now_ns = self.now_ns()
        sec, nanosec = split_stamp(now_ns)
        accepted = gid not in self.goals
        if accepted:
            self.goals[gid] = _Goal(gid, req.goal, now_ns, self.clock())
            self.status_changed = True
            g = req.goal.goal.pose.position
            log.info("action goal %s accepted: (%.2f, %.2f) m%s", gid.hex()[:8], g.x, g.y,
                     " from the given start" if req.goal.use_start else "")
            if self.on_goal is not None:
                self.on_goal(req.goal.goal)
        else:
            log.warning("action goal %s rejected: its id is already in use", gid.hex()[:8])
        return self.T.SendGoalResponse(req.client_guid, req.sequence_number, accepted, M.Time(sec, nanosec))

    def get_result(self, req: Any) -> Any | None:
        """``get_result``: the reply now when the goal is done or unknown, else None (answered by :meth:`step`)."""
        gid = _uuid(req.goal_id)
        goal = self.goals.get(gid)
        if goal is None:
            return self.T.GetResultResponse(req.client_guid, req.sequence_number, STATUS.UNKNOWN, self.T.Result())
        if goal.status in TERMINAL:
            return self.T.GetResultResponse(req.client_guid, req.sequence_number, goal.status, goal.result)
        goal.waiting_replies.append((req.client_guid, req.sequence_number))
        return None

    def cancel(self, req: Any) -> Any:
        """``cancel_goal`` (``action_msgs/srv/CancelGoal``): a zero id and zero stamp cancel every goal; a zero id
        and a stamp, every goal accepted at or before it; an id, that goal (and, with a stamp, those before it)."""
        gid = _uuid(req.goal_info.goal_id)
        stamp_ns = nanoseconds(req.goal_info.stamp)
        zero_id = gid == bytes(16)
        chosen: list[_Goal] = []
        for goal in self.goals.values():
            if (not zero_id and goal.goal_id == gid) or (zero_id and stamp_ns == 0) or \
                    (stamp_ns and goal.accepted_ns <= stamp_ns):
                chosen.append(goal)
        active = [g for g in chosen if g.status not in TERMINAL]
        response = self.T.CancelGoalResponse(req.client_guid, req.sequence_number)
        if not active:
            if not zero_id and gid not in self.goals:
                response.return_code = CANCEL.ERROR_UNKNOWN_GOAL_ID
            elif chosen:
                response.return_code = CANCEL.ERROR_GOAL_TERMINATED
            return response
        for goal in active:
            sec, nanosec = split_stamp(goal.accepted_ns)
            response.goals_canceling.append(self.T.GoalInfo(self.T.UUID(list(goal.goal_id)), M.Time(sec, nanosec)))
            self._finish(goal, STATUS.CANCELED, self._result())
            log.info("action goal %s canceled", goal.goal_id.hex()[:8])
        return response

    # -- work --------------------------------------------------------------------------------------------------
    def step(self) -> list[Any]:
        """Serve every executing goal that can be served (plan, or time out a waiting one), drop expired ones;
        returns the ``get_result`` replies now due."""
        replies: list[Any] = []
        now = self.clock()
        for goal in list(self.goals.values()):
            if goal.status in TERMINAL:
                if now - goal.done_t > self.settings.result_timeout_s:
                    del self.goals[goal.goal_id]
                    self.status_changed = True
                continue
            self._serve(goal, now)
            if goal.status in TERMINAL:
                replies += [self.T.GetResultResponse(guid, seq, goal.status, goal.result)
                            for guid, seq in goal.waiting_replies]
                goal.waiting_replies.clear()
        return replies

    def status_array(self) -> Any:
        out = self.T.GoalStatusArray()
        for goal in self.goals.values():
            sec, nanosec = split_stamp(goal.accepted_ns)
            info = self.T.GoalInfo(self.T.UUID(list(goal.goal_id)), M.Time(sec, nanosec))
            out.status_list.append(self.T.GoalStatus(info, goal.status))
        self.status_changed = False
        return out

    def _result(self, path: Any = None, seconds: float = 0.0, code: int = ERROR.NONE, msg: str = "") -> Any:
        kwargs: dict[str, Any] = {"path": path if path is not None else M.Path(),
                                  "planning_time": self.T.Duration(*split_stamp(max(0, round(float(seconds) * 1e9))))}
        if self.T.has_error_code:
            kwargs["error_code"] = int(code)
        if self.T.has_error_msg:
            kwargs["error_msg"] = str(msg)
        return self.T.Result(**kwargs)

    def _finish(self, goal: _Goal, status: int, result: Any) -> None:
        goal.status, goal.result, goal.done_t = status, result, self.clock()
        self.status_changed = True

    def _abort(self, goal: _Goal, code: int, msg: str, seconds: float = 0.0) -> None:
        name = next((k for k, v in vars(ERROR).items() if v == code), str(code))
        log.warning("action goal %s aborted: %s (%d): %s", goal.goal_id.hex()[:8], name, code, msg)
        self._count(f"action_{name.lower()}")
        self._finish(goal, STATUS.ABORTED, self._result(seconds=seconds, code=code, msg=msg))

    def _count(self, key: str) -> None:
        counts = getattr(getattr(self.core, "state", None), "counts", None)
        if isinstance(counts, dict):
            counts[key] = counts.get(key, 0) + 1

    def _serve(self, goal: _Goal, now: float) -> None:
        req = goal.request
        s, state = self.settings, self.core.state
        planner_id = str(req.planner_id)
        if s.planner_ids and planner_id and planner_id not in s.planner_ids:
            self._abort(goal, ERROR.INVALID_PLANNER, f"planner_id {planner_id!r} is not one of this server's "
                        f"{list(s.planner_ids)} (action.planner_ids)")
            return
        waited = now - goal.accepted_t
        if state.map is None:
            if waited >= s.wait_s:
                self._abort(goal, ERROR.TIMEOUT, f"no map within {s.wait_s:g} s (action.wait_s); the node reads "
                            "it from its map topic")
            return
        frame = state.frame
        try:
            goal_frame, goal_pose = pose_from_msg(req.goal)
            if req.use_start:
                start_frame, start_pose = pose_from_msg(req.start)
            else:
                start_frame, start_pose = frame, state.pose
        except MessageError as err:
            self._abort(goal, ERROR.UNKNOWN, f"malformed goal: {err}")
            return
        for what, f in (("goal", goal_frame), ("start", start_frame)):
            if f not in ("", frame):
                self._abort(goal, ERROR.TF_ERROR, f"the {what} is in frame {f!r}, the map in {frame!r}; this node "
                            "has no TF: give it in the map frame")
                return
        if start_pose is None:
            if waited >= s.wait_s:
                self._abort(goal, ERROR.TF_ERROR, f"no robot pose within {s.wait_s:g} s (action.wait_s) and "
                            "use_start is false; the node reads the pose from its pose topic")
            return
        event = self.core.query(np.asarray(start_pose, dtype=np.float64), goal_pose, trigger="action")
        seconds = event.seconds
        if event.error is not None:
            self._abort(goal, ERROR.UNKNOWN, event.error, seconds)
            return
        result = event.result
        if not result.success:
            self._abort(goal, PLANNER_ERRORS.get(result.code, ERROR.NO_VALID_PATH), f"{result.code}: {result.reason}",
                        seconds)
            return
        if seconds > s.timeout_s:
            self._abort(goal, ERROR.TIMEOUT, f"planning took {seconds:.2f} s, more than {s.timeout_s:g} s "
                        "(action.timeout_s)", seconds)
            return
        path = M.path(result.waypoints, event.frame_id, event.stamp_ns,
                      None if result.subgoal else float(goal_pose[2]))
        self._count("action_succeeded")
        log.info("action goal %s succeeded: %d poses, %.2f m%s, %.0f ms", goal.goal_id.hex()[:8],
                 len(result.waypoints), result.length_m, " to a sub-goal" if result.subgoal else "", 1000 * seconds)
        self._finish(goal, STATUS.SUCCEEDED, self._result(path, seconds))
        if self.on_path is not None:
            self.on_path(path, event)


# -- DDS -----------------------------------------------------------------------------------------------------------
def service_qos() -> Any:
    """ROS 2's services default: reliable, volatile, keep last 10."""
    return make_qos(True, False, 10)


def status_qos() -> Any:
    """``rcl_action``'s status topic: reliable, transient-local, keep last 1."""
    return make_qos(True, True, 1)


class ActionServer:
    """:class:`GoalLogic` on DDS: the three services' request readers and reply writers, the status and feedback
    writers, on ``participant``. The node attaches :attr:`conditions` to its wait set and calls :meth:`poll`."""

    def __init__(self, participant: Any, logic: GoalLogic) -> None:
        from cyclonedds.core import InstanceState, ReadCondition, SampleState, ViewState
        from cyclonedds.pub import DataWriter
        from cyclonedds.sub import DataReader
        from cyclonedds.topic import Topic

        self.logic = logic
        T, p = logic.T, participant
        names = action_topics(logic.settings.name)
        self.names = names
        sq = service_qos()
        self.send_goal_reader = DataReader(p, Topic(p, names["send_goal_request"], T.SendGoalRequest), qos=sq)
        self.send_goal_writer = DataWriter(p, Topic(p, names["send_goal_reply"], T.SendGoalResponse), qos=sq)
        self.get_result_reader = DataReader(p, Topic(p, names["get_result_request"], T.GetResultRequest), qos=sq)
        self.get_result_writer = DataWriter(p, Topic(p, names["get_result_reply"], T.GetResultResponse), qos=sq)
        self.cancel_reader = DataReader(p, Topic(p, names["cancel_request"], T.CancelGoalRequest), qos=sq)
        self.cancel_writer = DataWriter(p, Topic(p, names["cancel_reply"], T.CancelGoalResponse), qos=sq)
        self.status_writer = DataWriter(p, Topic(p, names["status"], T.GoalStatusArray), qos=status_qos())
        self.feedback_writer = DataWriter(p, Topic(p, names["feedback"], T.FeedbackMessage), qos=sq)
        mask = SampleState.Any | ViewState.Any | InstanceState.Any
        self.conditions = [ReadCondition(r, mask) for r in (self.send_goal_reader, self.get_result_reader,
                                                            self.cancel_reader)]
        self.status_writer.write(logic.status_array())

    @staticmethod
    def _take(reader: Any, what: str) -> list[Any]:
        try:
            samples = reader.take(N=64)
        except Exception as err:  # noqa: BLE001 - an undecodable request must not stop the node
            log.warning("undecodable %s request(s) dropped: %s: %s", what, type(err).__name__, err)
            return []
        return [s for s in samples if s is not None and getattr(getattr(s, "sample_info", None), "valid_data", True)]

    def poll(self) -> int:
        """Take and answer requests, serve goals, publish the status when it changed; returns requests taken."""
        taken = 0
        for req in self._take(self.send_goal_reader, "send_goal"):
            taken += 1
            self.send_goal_writer.write(self.logic.send_goal(req))
        for req in self._take(self.cancel_reader, "cancel_goal"):
            taken += 1
            self.cancel_writer.write(self.logic.cancel(req))
        replies = []
        for req in self._take(self.get_result_reader, "get_result"):
            taken += 1
            reply = self.logic.get_result(req)
            if reply is not None:
                replies.append(reply)
        replies += self.logic.step()
        if self.logic.status_changed:
            self.status_writer.write(self.logic.status_array())
        for reply in replies:
            self.get_result_writer.write(reply)
        return taken


class ActionClient:
    """A ``ComputePathToPose`` client on DDS, written from the same documents as the server (the desk simulator
    and the tests use it; a real Nav2 uses ``rclcpp_action``): send a goal, cancel it, wait for its result."""

    def __init__(self, participant: Any, name: str = "/compute_path_to_pose", distro: str = "jazzy") -> None:
        from cyclonedds.pub import DataWriter
        from cyclonedds.sub import DataReader
        from cyclonedds.topic import Topic

        self.T = T = types_for(distro)
        p = participant
        names = action_topics(name)
        sq = service_qos()
        self.send_goal_writer = DataWriter(p, Topic(p, names["send_goal_request"], T.SendGoalRequest), qos=sq)
        self.send_goal_reader = DataReader(p, Topic(p, names["send_goal_reply"], T.SendGoalResponse), qos=sq)
        self.get_result_writer = DataWriter(p, Topic(p, names["get_result_request"], T.GetResultRequest), qos=sq)
        self.get_result_reader = DataReader(p, Topic(p, names["get_result_reply"], T.GetResultResponse), qos=sq)
        self.cancel_writer = DataWriter(p, Topic(p, names["cancel_request"], T.CancelGoalRequest), qos=sq)
        self.cancel_reader = DataReader(p, Topic(p, names["cancel_reply"], T.CancelGoalResponse), qos=sq)
        self.status_reader = DataReader(p, Topic(p, names["status"], T.GoalStatusArray), qos=status_qos())
        self.guid = uuid_module.uuid4().int & ((1 << 64) - 1)
        self.seq = 0
        self._replies: dict[str, list[Any]] = {"send_goal": [], "get_result": [], "cancel": []}

    def server_ready(self) -> bool:
        """Whether the server's request readers and reply writers are all matched."""
        return all(bool(w.get_matched_subscriptions()) for w in (self.send_goal_writer, self.get_result_writer,
                                                                  self.cancel_writer)) and \
            all(bool(r.get_matched_publications()) for r in (self.send_goal_reader, self.get_result_reader,
                                                              self.cancel_reader))

    def wait_for_server(self, timeout_s: float = 30.0) -> bool:
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            if self.server_ready():
                return True
            time.sleep(0.05)
        return False

    def _next(self) -> int:
        self.seq += 1
        return self.seq

    def _reply(self, kind: str, reader: Any, seq: int, timeout_s: float) -> Any:
        end = time.monotonic() + timeout_s
        while True:
            for s in reader.take(N=64):
                if s is not None and getattr(getattr(s, "sample_info", None), "valid_data", True) and \
                        s.client_guid == self.guid:
                    self._replies[kind].append(s)
            for s in self._replies[kind]:
                if s.sequence_number == seq:
                    self._replies[kind].remove(s)
                    return s
            if time.monotonic() >= end:
                raise TimeoutError(f"no {kind} reply within {timeout_s} s")
            time.sleep(0.01)

    def send_goal(self, goal_xy_yaw: Any, *, start: Any = None, frame_id: str = "map", planner_id: str = "",
                  timeout_s: float = 10.0) -> tuple[bytes, Any]:
        """Send a goal (``start``: the start pose with ``use_start`` true; None: the robot's pose); returns the goal
        id and the ``send_goal`` reply."""
        gid = uuid_module.uuid4().bytes
        goal = self.T.Goal(M.pose_stamped(goal_xy_yaw, frame_id, 0),
                           M.pose_stamped(start if start is not None else (0.0, 0.0, 0.0), frame_id, 0),
                           planner_id, start is not None)
        seq = self._next()
        self.send_goal_writer.write(self.T.SendGoalRequest(self.guid, seq, self.T.UUID(list(gid)), goal))
        return gid, self._reply("send_goal", self.send_goal_reader, seq, timeout_s)

    def get_result(self, goal_id: bytes, timeout_s: float = 30.0) -> Any:
        seq = self._next()
        self.get_result_writer.write(self.T.GetResultRequest(self.guid, seq, self.T.UUID(list(goal_id))))
        return self._reply("get_result", self.get_result_reader, seq, timeout_s)

    def cancel(self, goal_id: bytes | None = None, timeout_s: float = 10.0) -> Any:
        """Cancel one goal (or, with None, every goal)."""
        seq = self._next()
        info = self.T.GoalInfo(self.T.UUID(list(goal_id or bytes(16))), M.Time(0, 0))
        self.cancel_writer.write(self.T.CancelGoalRequest(self.guid, seq, info))
        return self._reply("cancel", self.cancel_reader, seq, timeout_s)

    def plan(self, goal_xy_yaw: Any, *, start: Any = None, frame_id: str = "map", timeout_s: float = 30.0) -> Any:
        """Send a goal and wait for its ``get_result`` reply (status and result)."""
        gid, reply = self.send_goal(goal_xy_yaw, start=start, frame_id=frame_id, timeout_s=timeout_s)
        if not reply.accepted:
            raise RuntimeError("goal rejected")
        return self.get_result(gid, timeout_s)
