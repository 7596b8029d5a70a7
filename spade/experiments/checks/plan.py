"""``spade.plan``'s checks: the map and model files, a robot pose and a goal that differ, and a picture path that
is none of the inputs."""

from __future__ import annotations

import math

from omegaconf import DictConfig

from spade.experiments.checks.checkpoints import _check_checkpoint
from spade.experiments.checks.files import MODEL_SUFFIXES, _input_file, _map_files, _output_file, _point, check_paths
from spade.experiments.checks.values import _check_bool, _check_choice, _check_int, _check_number, _get
from spade.utils.errors import ConfigError


def validate_plan_config(cfg: DictConfig) -> None:
    """``spade.plan``'s checks: the map and model files, a robot pose and a goal that differ, and a picture path
    that is none of the inputs."""
    check_paths(cfg)
    maps = _map_files("map", _get(cfg, "map"))
    model = _input_file("model_path", _get(cfg, "model_path"),
                        "pass model=PATH (a student .ckpt from python -m spade.train or its .onnx / .pt export) or set "
                        "SPADE_PLANNER_MODEL", MODEL_SUFFIXES)
    if model.suffix.lower() == ".ckpt":
        _check_checkpoint("model_path", str(model), "student", "pass a student checkpoint (an expert does not plan)")
    start = _point(cfg, "start", 3, "X,Y,YAW")
    goal = _point(cfg, "goal", 2, "X,Y")
    if math.hypot(goal[0] - start[0], goal[1] - start[1]) < 1e-9:
        raise ConfigError(f"goal={goal[0]:g},{goal[1]:g} is the robot's own position (start); give a goal elsewhere")
    inputs = {"model_path": model, **{("map" if i == 0 else "the map's image"): p for i, p in enumerate(maps)}}
    _check_bool(cfg, "overwrite")
    _output_file("out", _get(cfg, "out"), inputs, "set out=plan.png (a new picture file)", (".png",),
                 _get(cfg, "overwrite"))
    _check_choice(cfg, "planner.far_goal", ["fail", "clip"])
    _check_number(cfg, "planner.threshold", 0, 1, low_open=True, high_open=True)
    _check_int(cfg, "planner.num_waypoints", 2)
    _check_number(cfg, "picture.context_m", 0)
    _check_int(cfg, "picture.width_px", 16)
