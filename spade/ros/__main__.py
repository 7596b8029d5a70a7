"""``python -m spade.ros [model=PATH] [domain_id=N] [key=value ...]``: the planner node on ROS 2's DDS topics.

See ``conf/ros.yaml`` for the options and :mod:`spade.ros` for the modules; ``docs/deployment.md`` for a robot.
A user error (a missing model, a bad option) is one ``error:`` line and exit status 2.

Examples::

    python -m spade.ros model=student.onnx                        # /map, /amcl_pose, /goal_pose -> /plan
    python -m spade.ros model=student.onnx topics.plan=/spade/plan domain_id=7 record=session_bag
    python -m spade.ros model=student.onnx replay=robot_bag replay_out=replanned_bag
    python -m spade.ros sim map=warehouse:1 model=student.onnx              # the desk simulator (conf/ros_sim.yaml)
"""

from __future__ import annotations

import sys

import hydra
from omegaconf import DictConfig

from spade.paths import CONFIG_PATH  # the configs (conf/ or the installed copy); registers the resolvers
from spade.utils.errors import ConfigError, exit_on_errors, run_entry_point, task
from spade.ros.launch import run
from spade.ros.sim import run_sim


def user_errors() -> tuple[type[BaseException], ...]:
    """What the node reports as one line: config errors, missing files, model files it cannot use, bad bags.
    (Not :func:`spade.config.refusals.user_errors`, which counts every package's user errors.)"""
    errors: list[type[BaseException]] = [ConfigError, FileNotFoundError]
    for module, name in (("spade.models.modelfile", "ModelFileError"), ("spade.deploy.onnx_runtime", "ModelFileError"),
                         ("spade.ros.recording", "BagError"), ("spade.deploy.mlflow_models", "RegistryError")):
        mod = sys.modules.get(module)
        if mod is not None and hasattr(mod, name):
            errors.append(getattr(mod, name))
    return tuple(errors)


@hydra.main(version_base="1.3", config_path=CONFIG_PATH, config_name="ros")
@task
def main(cfg: DictConfig) -> None:
    exit_on_errors(user_errors)(run)(cfg)


@hydra.main(version_base="1.3", config_path=CONFIG_PATH, config_name="ros_sim")
@task
def sim_main(cfg: DictConfig) -> None:
    status = exit_on_errors(user_errors)(run_sim)(cfg)
    if status:
        raise SystemExit(status)


def cli() -> None:
    """The ``spade-ros`` console script (``spade-ros sim ...``: the desk simulator)."""
    args = sys.argv[1:]
    sim = bool(args) and args[0] == "sim"
    if sim:
        args = args[1:]
    sys.argv = [sys.argv[0], *(("model_path=" + a[len("model="):]) if a.startswith("model=") else a for a in args)]
    run_entry_point(sim_main if sim else main)


if __name__ == "__main__":
    cli()
