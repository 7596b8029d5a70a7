"""The planner node on the wire: ROS 2's DDS topics with ``cyclonedds``, no ROS install.

A ROS 2 topic ``/plan`` of type ``nav_msgs/msg/Path`` is the DDS topic ``rt/plan`` of type
``nav_msgs::msg::dds_::Path_`` (:mod:`spade.ros.messages`); any ROS 2 node on the same domain id (``ROS_DOMAIN_ID``)
whose RMW reaches this participant (Cyclone DDS natively; Fast DDS over UDP) exchanges messages with it. QoS follows
Nav2: the map is read reliable + transient-local (map_server latches it), AMCL's pose reliable + transient-local (AMCL
latches it too), a ``PoseStamped`` pose and the goal reliable + volatile (RViz2's goal publisher is volatile; a
transient-local reader would not match a volatile writer), the plan is written reliable + transient-local (a late
subscriber gets the last plan; volatile subscribers such as RViz2's Path display match too).

:class:`PlannerNode` reads the three topics in one thread (a DDS wait set), hands each sample to
:class:`spade.ros.core.PlannerCore` and publishes what it plans: the ``nav_msgs/Path`` in the map frame (every pose
stamped, oriented along the path, the last one at the goal's yaw) and its confidence (``std_msgs/Float32``). A
sample the DDS layer cannot decode is logged and dropped like a malformed message.
"""

from __future__ import annotations

import contextlib
import logging
import math
import signal
import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from cyclonedds.core import InstanceState, ReadCondition, SampleState, ViewState, WaitSet
from cyclonedds.domain import DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.qos import Qos
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration

from spade.ros import messages as M
from spade.ros.action import ActionServer, GoalLogic
from spade.ros.core import PlanEvent, PlannerCore
from spade.ros.dds import make_qos, ros_topic
from spade.ros.node_options import QOS_KEYS, check_qos

__all__ = ["PlannerNode", "QOS_KEYS", "Topics", "check_qos"]

log = logging.getLogger("spade.ros")

POSE_TYPES = {"amcl": M.PoseWithCovarianceStamped, "PoseWithCovarianceStamped": M.PoseWithCovarianceStamped,
              "stamped": M.PoseStamped, "PoseStamped": M.PoseStamped}


@dataclass(frozen=True)
class Topics:
    """ROS 2 topic names (with or without the ``rt/`` prefix)."""

    map: str = "/map"
    pose: str = "/amcl_pose"
    goal: str = "/goal_pose"
    plan: str = "/plan"
    confidence: str = "/plan_confidence"  # empty: not published


def _qos(spec: Mapping[str, Any] | None, default: Qos, default_spec: tuple[bool, bool, int]) -> Qos:
    if not spec:
        return default
    reliable, transient, depth = default_spec
    return make_qos(spec["reliability"] == "reliable" if "reliability" in spec else reliable,
                    spec["durability"] == "transient_local" if "durability" in spec else transient,
                    int(spec.get("depth", depth)))


class PlannerNode:
    """The DDS side of the planner node (see the module docstring).

    Args:
        core: the node's logic, with its planner.
        domain_id: the DDS domain (ROS 2's ``ROS_DOMAIN_ID``).
        topics: the ROS topic names.
        pose_type: ``amcl`` (``PoseWithCovarianceStamped``, default) or ``stamped`` (``PoseStamped``).
        qos: per-topic overrides, e.g. ``{"map": {"reliability": "reliable", "durability": "transient_local",
            "depth": 1}}`` (:func:`check_qos`).
        recorder: a :class:`spade.ros.recording.NodeRecorder` (or None).
        action: :class:`spade.ros.action.ActionSettings`; when enabled, the ``ComputePathToPose`` action server.
    """

    def __init__(self, core: PlannerCore, *, domain_id: int = 0, topics: Topics | None = None,
                 pose_type: str = "amcl", qos: Mapping[str, Mapping[str, Any]] | None = None,
                 recorder: Any = None, action: Any = None) -> None:
        if pose_type not in POSE_TYPES:
            raise ValueError(f"pose_type must be one of {sorted(POSE_TYPES)}, got {pose_type!r}")
        self.core = core
        self.topics = topics or Topics()
        self.recorder = recorder
        qos = check_qos(qos)
        self.participant = DomainParticipant(int(domain_id))
        p = self.participant
        # AMCL latches its pose (transient-local): a robot standing still publishes no new one, so the node reads the
        # last one; a PoseStamped source is taken to be volatile (a transient-local reader would not match it).
        amcl = POSE_TYPES[pose_type] is M.PoseWithCovarianceStamped
        specs = {"map": (True, True, 1), "pose": (True, amcl, 1), "goal": (True, False, 10), "plan": (True, True, 1),
                 "confidence": (True, True, 1)}
        q = {k: _qos(qos.get(k), make_qos(*v), v) for k, v in specs.items()}
        self.map_reader = DataReader(p, Topic(p, ros_topic(self.topics.map), M.OccupancyGrid), qos=q["map"])
        self.pose_reader = DataReader(p, Topic(p, ros_topic(self.topics.pose), POSE_TYPES[pose_type]), qos=q["pose"])
        self.goal_reader = DataReader(p, Topic(p, ros_topic(self.topics.goal), M.PoseStamped), qos=q["goal"])
        self.plan_writer = DataWriter(p, Topic(p, ros_topic(self.topics.plan), M.Path), qos=q["plan"])
        self.confidence_writer = (DataWriter(p, Topic(p, ros_topic(self.topics.confidence), M.Float32),
                                             qos=q["confidence"]) if self.topics.confidence else None)
        self.waitset = WaitSet(p)
        mask = SampleState.Any | ViewState.Any | InstanceState.Any
        self._readers = [("map", self.map_reader, core.handle_map), ("pose", self.pose_reader, core.handle_pose),
                         ("goal", self.goal_reader, core.handle_goal)]
        self._conditions = [ReadCondition(r, mask) for _, r, _ in self._readers]
        self.action = None
        if action is not None and action.enabled:
            self.action = ActionServer(p, GoalLogic(core, action, on_path=self._publish_path,
                                                    on_goal=lambda goal: self._notify("goal", goal)))
            self._conditions += self.action.conditions
        for c in self._conditions:
            self.waitset.attach(c)
        self.stop_event = threading.Event()
        self.published = 0
        self.observers: list[Any] = []  # e.g. the live Foxglove server: on_message(name, msg), on_plan(event, path)

    # -- publishing ----------------------------------------------------------------------------------------------
    def publish(self, event: PlanEvent) -> None:
        """Publish a successful plan (a failed one publishes nothing: the failure is logged by the core)."""
        if not event.success:
            return
        result = event.result
        goal_yaw = None if result.subgoal else event.goal_yaw
        msg = M.path(result.waypoints, event.frame_id, event.stamp_ns, goal_yaw)
        self._publish_path(msg, event)
        if self.confidence_writer is not None and math.isfinite(event.confidence):
            confidence = M.Float32(float(event.confidence))
            self.confidence_writer.write(confidence)
            if self.recorder is not None:
                self.recorder.message("confidence", confidence)
        self.published += 1

    def _publish_path(self, msg: Any, event: PlanEvent) -> None:
        """Write a ``nav_msgs/Path`` on the plan topic (a topic goal's plan, or an action goal's as
        ``planner_server`` publishes its own), record it, tell the observers."""
        self.plan_writer.write(msg)
        if self.recorder is not None:
            self.recorder.message("plan", msg)
            if hasattr(self.recorder, "plan"):
                self.recorder.plan(event, msg)
        for observer in self.observers:
            try:
                observer.on_plan(event, msg)
            except Exception as err:  # noqa: BLE001 - a viewer must never stop the node
                log.warning("observer %s failed on a plan: %s: %s", type(observer).__name__, type(err).__name__, err)

    def _notify(self, name: str, msg: Any) -> None:
        """Tell the observers of a message the node took (an action goal's pose is a ``goal``)."""
        for observer in self.observers:
            try:
                observer.on_message(name, msg)
            except Exception as err:  # noqa: BLE001 - a viewer must never stop the node
                log.warning("observer %s failed on a %s message: %s", type(observer).__name__, name, err)

    # -- the loop ------------------------------------------------------------------------------------------------
    def spin_once(self, timeout_s: float = 0.1) -> int:
        """Wait up to ``timeout_s`` for samples, handle them; returns how many were taken."""
        self.waitset.wait(duration(seconds=timeout_s))
        taken = 0
        for name, reader, handle in self._readers:
            try:
                samples = reader.take(N=64)
            except Exception as err:  # noqa: BLE001 - an undecodable sample must not stop the node
                log.warning("undecodable %s sample(s) dropped: %s: %s", name, type(err).__name__, err)
                continue
            # Maps and poses: only the latest one matters; every goal is handled in order (the last one wins).
            samples = [s for s in samples if s is not None and not _is_invalid(s)]
            if name in ("map", "pose"):
                samples = samples[-1:]
            for sample in samples:
                taken += 1
                if self.recorder is not None:
                    self.recorder.message(name, sample)
                self._notify(name, sample)
                try:
                    event = handle(sample)
                except Exception as err:  # noqa: BLE001 - the core logs and survives; this is its last guard
                    log.exception("handling a %s message failed: %s", name, err)
                    continue
                if event is not None:
                    self.publish(event)
        try:
            event = self.core.tick()
        except Exception as err:  # noqa: BLE001 - the core logs and survives; this is its last guard
            log.exception("a deferred re-plan failed: %s", err)
            event = None
        if event is not None:
            self.publish(event)
        if self.action is not None:
            try:
                taken += self.action.poll()
            except Exception as err:  # noqa: BLE001 - a bad request must not stop the node
                log.exception("the action server failed: %s", err)
        return taken

    def spin(self, max_seconds: float | None = None) -> None:
        """Run until :meth:`stop`, SIGINT/SIGTERM (in the main thread) or ``max_seconds``."""
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                signal.signal(sig, lambda *_: self.stop_event.set())
        end = None if max_seconds is None else time.monotonic() + float(max_seconds)
        while not self.stop_event.is_set() and (end is None or time.monotonic() < end):
            self.spin_once(0.1)

    def stop(self) -> None:
        self.stop_event.set()

    def close(self) -> None:
        for c in self._conditions:
            with contextlib.suppress(Exception):  # tearing down
                self.waitset.detach(c)
        # Entities are deleted with the participant when it is garbage-collected.
        self._readers.clear()


def _is_invalid(sample: Any) -> bool:
    """A sample that only carries an instance state change (a disposed or unregistered writer), no data."""
    info = getattr(sample, "sample_info", None)
    return info is not None and not getattr(info, "valid_data", True)
