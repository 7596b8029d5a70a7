"""The ``nav2_msgs/action/ComputePathToPose`` action on the wire, as DDS types (``cyclonedds.idl``).

A ROS 2 action ``/compute_path_to_pose`` is three services and two topics (``rcl_action``'s names; ``rmw_cyclonedds``
prefixes a service's request topic with ``rq/`` and appends ``Request``, its reply topic ``rr/`` ... ``Reply``)::

    rq/compute_path_to_pose/_action/send_goalRequest    nav2_msgs::action::dds_::ComputePathToPose_SendGoal_Request_
    rr/compute_path_to_pose/_action/send_goalReply      nav2_msgs::action::dds_::ComputePathToPose_SendGoal_Response_
    rq/compute_path_to_pose/_action/get_resultRequest   nav2_msgs::action::dds_::ComputePathToPose_GetResult_Request_
    rr/compute_path_to_pose/_action/get_resultReply     nav2_msgs::action::dds_::ComputePathToPose_GetResult_Response_
    rq/compute_path_to_pose/_action/cancel_goalRequest  action_msgs::srv::dds_::CancelGoal_Request_
    rr/compute_path_to_pose/_action/cancel_goalReply    action_msgs::srv::dds_::CancelGoal_Response_
    rt/compute_path_to_pose/_action/feedback            nav2_msgs::action::dds_::ComputePathToPose_FeedbackMessage_
    rt/compute_path_to_pose/_action/status              action_msgs::msg::dds_::GoalStatusArray_

``rmw_cyclonedds`` puts its service header in front of every request and reply: the client's 64-bit id
(``uint64 guid``) and the request's sequence number (``int64 seq``); the reply echoes both. Here they are the first
two fields of every request and reply type (``client_guid``, ``sequence_number``): on the wire (XCDR1, final) a
struct's members follow each other with no framing, so this is the same byte stream.

The result's layout differs between distributions (``nav2_msgs`` of each):

- **humble**: ``nav_msgs/Path path``, ``builtin_interfaces/Duration planning_time`` (no error code: a failed goal is
  only its ABORTED status);
- **iron**: + ``uint16 error_code``;
- **jazzy** (and later, the current LTS, the default): + ``uint16 error_code``, ``string error_msg``.

The goal (``PoseStamped goal``, ``PoseStamped start``, ``string planner_id``, ``bool use_start``) and the empty
feedback (ROS 2 gives an empty message one ``uint8 structure_needs_at_least_one_member``) are the same in all three.
(No ``from __future__ import annotations``: cyclonedds reads the field annotations as types.)
"""

from dataclasses import dataclass, field
from types import SimpleNamespace, new_class

import cyclonedds.idl.annotations as annotate
from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import array, int8, int32, int64, sequence, uint8, uint16, uint32, uint64

from spade.ros.messages import Path, PoseStamped, Time

__all__ = ["CANCEL", "DISTROS", "ERROR", "STATUS", "action_topics", "types_for"]

DISTROS = ("humble", "iron", "jazzy")

# action_msgs/msg/GoalStatus
STATUS = SimpleNamespace(UNKNOWN=0, ACCEPTED=1, EXECUTING=2, CANCELING=3, SUCCEEDED=4, CANCELED=5, ABORTED=6)
# action_msgs/srv/CancelGoal (response return_code)
CANCEL = SimpleNamespace(ERROR_NONE=0, ERROR_REJECTED=1, ERROR_UNKNOWN_GOAL_ID=2, ERROR_GOAL_TERMINATED=3)
# nav2_msgs/action/ComputePathToPose result error codes (Iron and later)
ERROR = SimpleNamespace(NONE=0, UNKNOWN=200, INVALID_PLANNER=201, TF_ERROR=202, START_OUTSIDE_MAP=203,
                        GOAL_OUTSIDE_MAP=204, START_OCCUPIED=205, GOAL_OCCUPIED=206, TIMEOUT=207, NO_VALID_PATH=208)


def action_topics(name: str) -> dict[str, str]:
    """The DDS topics of the ROS 2 action ``name`` (``/compute_path_to_pose`` or without the slash)."""
    base = str(name).strip().strip("/")
    if not base:
        raise ValueError("an action name must not be empty")
    return {
        "send_goal_request": f"rq/{base}/_action/send_goalRequest",
        "send_goal_reply": f"rr/{base}/_action/send_goalReply",
        "get_result_request": f"rq/{base}/_action/get_resultRequest",
        "get_result_reply": f"rr/{base}/_action/get_resultReply",
        "cancel_request": f"rq/{base}/_action/cancel_goalRequest",
        "cancel_reply": f"rr/{base}/_action/cancel_goalReply",
        "feedback": f"rt/{base}/_action/feedback",
        "status": f"rt/{base}/_action/status",
    }


# -- shared messages -----------------------------------------------------------------------------------------------
@dataclass
@annotate.final
class UUID(IdlStruct, typename="unique_identifier_msgs::msg::dds_::UUID_"):
    uuid: array[uint8, 16] = field(default_factory=lambda: [0] * 16)


@dataclass
@annotate.final
class Duration(IdlStruct, typename="builtin_interfaces::msg::dds_::Duration_"):
    sec: int32 = 0
    nanosec: uint32 = 0


@dataclass
@annotate.final
class GoalInfo(IdlStruct, typename="action_msgs::msg::dds_::GoalInfo_"):
    goal_id: UUID = field(default_factory=UUID)
    stamp: Time = field(default_factory=Time)


@dataclass
@annotate.final
class GoalStatus(IdlStruct, typename="action_msgs::msg::dds_::GoalStatus_"):
    goal_info: GoalInfo = field(default_factory=GoalInfo)
    status: int8 = 0


@dataclass
@annotate.final
class GoalStatusArray(IdlStruct, typename="action_msgs::msg::dds_::GoalStatusArray_"):
    status_list: sequence[GoalStatus] = field(default_factory=list)


@dataclass
@annotate.final
class CancelGoalRequest(IdlStruct, typename="action_msgs::srv::dds_::CancelGoal_Request_"):
    client_guid: uint64 = 0
    sequence_number: int64 = 0
    goal_info: GoalInfo = field(default_factory=GoalInfo)


@dataclass
@annotate.final
class CancelGoalResponse(IdlStruct, typename="action_msgs::srv::dds_::CancelGoal_Response_"):
    client_guid: uint64 = 0
    sequence_number: int64 = 0
    return_code: int8 = 0
    goals_canceling: sequence[GoalInfo] = field(default_factory=list)


# -- ComputePathToPose ----------------------------------------------------------------------------------------------
@dataclass
@annotate.final
class Goal(IdlStruct, typename="nav2_msgs::action::dds_::ComputePathToPose_Goal_"):
    goal: PoseStamped = field(default_factory=PoseStamped)
    start: PoseStamped = field(default_factory=PoseStamped)
    planner_id: str = ""
    use_start: bool = False


@dataclass
@annotate.final
class Feedback(IdlStruct, typename="nav2_msgs::action::dds_::ComputePathToPose_Feedback_"):
    structure_needs_at_least_one_member: uint8 = 0


@dataclass
@annotate.final
class FeedbackMessage(IdlStruct, typename="nav2_msgs::action::dds_::ComputePathToPose_FeedbackMessage_"):
    goal_id: UUID = field(default_factory=UUID)
    feedback: Feedback = field(default_factory=Feedback)


@dataclass
@annotate.final
class SendGoalRequest(IdlStruct, typename="nav2_msgs::action::dds_::ComputePathToPose_SendGoal_Request_"):
    client_guid: uint64 = 0
    sequence_number: int64 = 0
    goal_id: UUID = field(default_factory=UUID)
    goal: Goal = field(default_factory=Goal)


@dataclass
@annotate.final
class SendGoalResponse(IdlStruct, typename="nav2_msgs::action::dds_::ComputePathToPose_SendGoal_Response_"):
    client_guid: uint64 = 0
    sequence_number: int64 = 0
    accepted: bool = False
    stamp: Time = field(default_factory=Time)


@dataclass
@annotate.final
class GetResultRequest(IdlStruct, typename="nav2_msgs::action::dds_::ComputePathToPose_GetResult_Request_"):
    client_guid: uint64 = 0
    sequence_number: int64 = 0
    goal_id: UUID = field(default_factory=UUID)


def _struct(name: str, typename: str, members: list[tuple[str, object, object]]) -> type:
    """A final IDL struct of ``(field, type, default)`` rows, as the ``@dataclass @annotate.final`` classes above."""
    def body(ns: dict) -> None:
        ns["__module__"] = __name__
        for member, kind, default in members:
            ns["__annotations__"][member] = kind
            ns[member] = default
    return dataclass(annotate.final(new_class(name, (IdlStruct,), {"typename": typename}, body)))


# The result grows by distribution (humble: path, planning_time; iron: + error_code; jazzy: + error_msg); the
# GetResult response wraps it behind the service header and the goal's status.
_RESULTS = {}
for _distro, _n in zip(DISTROS, (2, 3, 4)):
    _result = _struct(f"Result{_distro.title()}", "nav2_msgs::action::dds_::ComputePathToPose_Result_", [
        ("path", Path, field(default_factory=Path)), ("planning_time", Duration, field(default_factory=Duration)),
        ("error_code", uint16, 0), ("error_msg", str, "")][:_n])
    _RESULTS[_distro] = (_result, _struct(
        f"GetResultResponse{_distro.title()}", "nav2_msgs::action::dds_::ComputePathToPose_GetResult_Response_",
        [("client_guid", uint64, 0), ("sequence_number", int64, 0), ("status", int8, 0),
         ("result", _result, field(default_factory=_result))]))


def types_for(distro: str) -> SimpleNamespace:
    """The action's DDS types for a ROS 2 distribution (``humble``, ``iron``, ``jazzy``; later ones: ``jazzy``)."""
    key = str(distro).strip().lower()
    if key not in _RESULTS:
        raise ValueError(f"ROS 2 distribution {distro!r}: the ComputePathToPose layouts known are {list(DISTROS)} "
                         "(later distributions use jazzy's)")
    result, get_result_response = _RESULTS[key]
    return SimpleNamespace(
        distro=key, Goal=Goal, Result=result, Feedback=Feedback, FeedbackMessage=FeedbackMessage,
        SendGoalRequest=SendGoalRequest, SendGoalResponse=SendGoalResponse, GetResultRequest=GetResultRequest,
        GetResultResponse=get_result_response, CancelGoalRequest=CancelGoalRequest,
        CancelGoalResponse=CancelGoalResponse, GoalStatusArray=GoalStatusArray, GoalStatus=GoalStatus,
        GoalInfo=GoalInfo, UUID=UUID, Duration=Duration,
        has_error_code=key in ("iron", "jazzy"), has_error_msg=key == "jazzy",
    )
