"""The planner node's option checks that need no DDS (the replay and the config check use them before any work)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

__all__ = ["DURABILITY", "QOS_KEYS", "RELIABILITY", "TOPIC_KEYS", "check_qos"]

TOPIC_KEYS = ("map", "pose", "goal", "plan", "confidence")
QOS_KEYS = TOPIC_KEYS
RELIABILITY = ("reliable", "best_effort")
DURABILITY = ("volatile", "transient_local")


def check_qos(qos: Mapping[str, Any] | None) -> dict[str, dict[str, Any]]:
    """The per-topic QoS overrides, checked: topics among :data:`QOS_KEYS`, ``reliability`` reliable |
    best_effort, ``durability`` volatile | transient_local, ``depth`` a positive integer; null entries keep the
    defaults. ValueError names the option and what it takes."""
    out: dict[str, dict[str, Any]] = {}
    for topic, spec in dict(qos or {}).items():
        if topic not in QOS_KEYS:
            raise ValueError(f"qos.{topic}: no such topic; the QoS overrides are for {list(QOS_KEYS)}")
        if spec is None:
            continue
        if not isinstance(spec, Mapping):
            raise ValueError(f"qos.{topic}={spec!r}: give a mapping, e.g. "
                             f"'qos={{{topic}: {{reliability: reliable, durability: volatile, depth: 1}}}}'")
        checked: dict[str, Any] = {}
        for key, value in spec.items():
            if value is None:
                continue
            if key == "reliability":
                if value not in RELIABILITY:
                    raise ValueError(f"qos.{topic}.reliability={value!r}: use reliable or best_effort")
            elif key == "durability":
                if value not in DURABILITY:
                    raise ValueError(f"qos.{topic}.durability={value!r}: use volatile or transient_local")
            elif key == "depth":
                if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                    raise ValueError(f"qos.{topic}.depth={value!r}: a positive integer (keep-last depth)")
            else:
                raise ValueError(f"qos.{topic}.{key}: no such QoS setting; use reliability, durability, depth")
            checked[key] = value
        if checked:
            out[topic] = checked
    return out
