"""``python -m spade.plan MAP.yaml start=X,Y,YAW goal=X,Y [model=PATH] [key=value ...]``: plan once and show it.

Loads a student (checkpoint or export; ``model=``, short for ``model_path=``, or the ``SPADE_PLANNER_MODEL``
environment variable), plans from the robot pose ``start`` (map-frame metres, yaw in radians as in ROS) to
``goal`` (metres) on the map with :class:`spade.planner.Planner`, prints the waypoints (one ``x y`` line each,
metres) and writes a PNG: the map around the student's robot-frame window, the window, the predicted path
probabilities, the robot and its heading (blue), the goal (red) and the waypoints (green). ``mcap=PATH`` also writes
the plan as a ROS 2 MCAP recording (map, robot pose, goal, path, window, confidence as ROS 2 messages, for Foxglove,
``ros2 bag play`` and ``mcap-ros2-support``; :func:`spade.ros.recording.write_plan_bag`). Exits with status 1
when no path was found (the PNG and the recording are written all the same, for debugging).

Examples::

    python -m spade.plan ../shared/maps/turtlebot3/turtlebot3_world.yaml start=-2,-0.5,1.57 goal=-1.5,1 model=s.ckpt
    python -m spade.plan warehouse:101 start=3,4,0 goal=6,6 model=student.onnx out=plan.png planner.far_goal=clip
    python -m spade.plan MAP.yaml start=-2,-0.5,1.57 goal=-1.5,1 model=student.onnx mcap=plan.mcap

A leading positional map becomes ``map=...`` and ``start=X,Y,YAW`` becomes ``start=[X,Y,YAW]``
(:func:`spade.deploy.plan_command.rewrite_argv`); the work is :func:`spade.deploy.plan_command.run_plan`.
"""

from __future__ import annotations

import sys

import hydra
from omegaconf import DictConfig, OmegaConf

from spade.paths import CONFIG_PATH  # the configs (conf/ or the installed copy); registers the resolvers
from spade.utils.errors import run_entry_point, task
from spade.deploy.plan_command import rewrite_argv, run_plan
from spade.deploy.plan_picture import plan_text
from spade.config.plan_checks import validate_plan_config
from spade.deploy.mlflow_models import is_model_uri, resolve_model
from spade.deploy.plan_picture import load_map
from spade.ros.recording import check_recording_path, write_plan_bag


def _resolve_model_uri(cfg: DictConfig) -> None:
    """``model=models:/NAME@ALIAS`` (or ``runs:/...``): the registered ONNX student, downloaded from the project's
    MLflow store (``paths.mlflow_tracking_uri``: ``MLFLOW_TRACKING_URI``, else ``logs/mlflow.db`` under SPADE_HOME or
    the current folder) into ``paths.registry_cache_dir``; ``model_path`` becomes the file. A store that is not there
    is named in the refusal, never created."""
    value = cfg.get("model_path")
    if value and is_model_uri(str(value)):
        cfg.model_path = str(resolve_model(str(value), OmegaConf.select(cfg, "paths.mlflow_tracking_uri"),
                                           OmegaConf.select(cfg, "paths.registry_cache_dir")))


def _checked_plan(cfg: DictConfig):  # noqa: ANN202
    """The config and inputs checked first (one ``error:`` line, exit 2), then the query."""
    _resolve_model_uri(cfg)
    validate_plan_config(cfg)  # map and model files, pose and goal, a picture that is none of the inputs
    mcap = check_recording_path(cfg.get("mcap"))
    result, png = run_plan(cfg)
    if mcap is not None:
        write_plan_bag(mcap, load_map(cfg.map), [result])
    return result, png, mcap


@hydra.main(version_base="1.3", config_path=CONFIG_PATH, config_name="plan")
@task
def main(cfg: DictConfig) -> None:
    from spade.config.refusals import exit_on_user_error

    result, png, mcap = exit_on_user_error(_checked_plan)(cfg)
    print(plan_text(result, str(cfg.map), png), flush=True)
    if mcap is not None:
        print(f"# recording: {mcap}", flush=True)
    if not result.success:
        raise SystemExit(1)


if __name__ == "__main__":
    sys.argv = [sys.argv[0], *rewrite_argv(sys.argv[1:])]
    run_entry_point(main)
