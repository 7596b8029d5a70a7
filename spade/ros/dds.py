"""ROS 2 topics on DDS: a ROS 2 topic's DDS name and a ROS 2 QoS profile as a ``cyclonedds`` QoS, shared by the
node (:mod:`spade.ros.node`), its Nav2 action (:mod:`spade.ros.action`) and the desk simulator
(:mod:`spade.ros.sim`)."""

from __future__ import annotations

from cyclonedds.qos import Policy, Qos
from cyclonedds.util import duration

__all__ = ["make_qos", "ros_topic"]


def ros_topic(name: str) -> str:
    """The DDS topic of a ROS 2 topic name: ``/plan`` and ``plan`` -> ``rt/plan``; ``rt/plan`` stays."""
    name = str(name).strip()
    if name.startswith("rt/"):
        return name
    return "rt/" + name.lstrip("/")


def make_qos(reliable: bool = True, transient_local: bool = False, depth: int = 1) -> Qos:
    """A DDS QoS as a ROS 2 profile states it: reliability, durability, keep-last depth."""
    return Qos(Policy.Reliability.Reliable(duration(seconds=1)) if reliable else Policy.Reliability.BestEffort,
               Policy.Durability.TransientLocal if transient_local else Policy.Durability.Volatile,
               Policy.History.KeepLast(int(depth)))
