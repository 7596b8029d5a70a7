"""The planner API: ``from spade.planner import Planner``.

    planner = Planner("student.ckpt")            # or the ONNX export: Planner("student.onnx")
    result = planner.plan("map.yaml", start=(1.0, 2.0), goal=(3.5, 4.0))   # map-frame metres
    if result.success:
        print(result.waypoints)                   # (K, 2) metres, start -> goal
    else:
        print(result.code, result.reason)

Implementation: :mod:`spade.deploy.planner`.
"""

from spade.deploy.planner import PlannerConfigError, PlanResult, Planner, WindowPlacement

__all__ = ["PlanResult", "Planner", "PlannerConfigError", "WindowPlacement"]
