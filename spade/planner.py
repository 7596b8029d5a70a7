"""The planner API: ``from spade.planner import Planner``.

    planner = Planner("student.ckpt")            # or its export: Planner("student.onnx")
    result = planner.plan("map.yaml", (1.0, 2.0, 0.5), goal=(3.5, 4.0))   # robot pose (x, y, yaw), goal: map metres
    if result.success:
        print(result.waypoints)                   # (K, 2) metres, robot -> goal
    else:
        print(result.code, result.reason)

Implementation: :mod:`spade.deploy.student_planner`.
"""

from spade.deploy.plan_result import PlannerConfigError, PlanResult
from spade.deploy.robot_window import PlanWindow
from spade.deploy.student_planner import Planner

__all__ = ["PlanResult", "PlanWindow", "Planner", "PlannerConfigError"]
