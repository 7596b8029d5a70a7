"""The robot a planner drives against the robot its student was trained for: the footprint a model file records
(``data.footprint``: robot radius and inflation) checked against the robot's, refused or warned about."""

from __future__ import annotations

import math
import warnings
from pathlib import Path
from typing import Any

from spade.deploy.plan_result import PlannerConfigError

__all__ = ["check_footprint", "describe_footprint"]


def describe_footprint(footprint: dict[str, Any] | None) -> str:
    """``robot radius 0.105 m + inflation 0.55 m`` (``assumed`` when the model file predates the record)."""
    if not footprint:
        return "robot footprint not recorded"
    return (f"trained for a robot radius {footprint['radius_m']:g} m + inflation {footprint['inflation_radius_m']:g} m"
            + (" (assumed: the model file predates footprint records)" if footprint.get("assumed") else ""))


def check_footprint(recorded: Any, radius_m: float | None, inflation_m: float | None, mismatch: str,
                    path: str | Path) -> dict[str, Any] | None:
    """The model's footprint (``data.footprint``), checked against the robot's when given: a robot radius or an
    inflation that differs is refused (PlannerConfigError) or, with ``mismatch="warn"``, warned about."""
    if mismatch not in ("refuse", "warn"):
        raise PlannerConfigError(f"footprint_mismatch must be 'refuse' or 'warn', got {mismatch!r}")
    footprint = None
    if isinstance(recorded, dict) and all(isinstance(recorded.get(k), (int, float)) and not isinstance(
            recorded.get(k), bool) for k in ("radius_m", "inflation_radius_m")):
        footprint = {"radius_m": float(recorded["radius_m"]), "inflation_radius_m": float(recorded["inflation_radius_m"])}
        if recorded.get("assumed"):
            footprint["assumed"] = True
    given = {"radius_m": radius_m, "inflation_radius_m": inflation_m}
    for key, value in given.items():
        if value is not None and (isinstance(value, bool) or not isinstance(value, (int, float))
                                  or not math.isfinite(float(value)) or float(value) < 0):
            name = "robot_radius_m" if key == "radius_m" else key
            raise PlannerConfigError(f"{name}={value!r}: a robot size in metres, >= 0 (or null: not checked)")
    asked = {k: float(v) for k, v in given.items() if v is not None}
    if not asked:
        return footprint
    if footprint is None:
        warnings.warn(f"{path}: the model file records no robot footprint, so the robot's (radius "
                      f"{asked.get('radius_m', '?')} m, inflation {asked.get('inflation_radius_m', '?')} m) cannot "
                      "be checked; export it again with this SPADE", UserWarning, stacklevel=3)
        return None
    differ = [k for k, v in asked.items() if abs(v - footprint[k]) > 1e-6]
    if not differ:
        return footprint
    names = {"radius_m": "robot_radius_m", "inflation_radius_m": "inflation_radius_m"}
    what = ", ".join(f"{names[k]} {asked[k]:g} m (the model's {footprint[k]:g} m)" for k in differ)
    message = (f"{path}: this robot differs from the one the model's demonstrations assumed: {what}. Its plans keep "
               "the trained robot's clearances; generate data for this robot (python -m spade.annotate "
               "robot.radius_m=... robot.inflation_radius_m=...; docs/how-to/own-map-footprint.md) and train on it, "
               "or pass footprint_mismatch=warn to plan anyway")
    if footprint.get("assumed"):
        message += " (the model file predates footprint records: its footprint is assumed, so this is only a warning)"
    if mismatch == "refuse" and not footprint.get("assumed"):
        raise PlannerConfigError(message)
    warnings.warn(message, UserWarning, stacklevel=3)
    return footprint

