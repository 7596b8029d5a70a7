"""``spade.plan``'s checks: the map and model files, a robot pose and a goal that differ, and a picture path that
is none of the inputs."""

from __future__ import annotations

import math

from omegaconf import DictConfig

from spade.config.checkpoint_checks import check_checkpoint
from spade.config.file_checks import MODEL_SUFFIXES, input_file, map_files, output_file, point, check_paths
from spade.config.values import check_bool, check_choice, check_int, check_number, get
from spade.utils.errors import ConfigError


def validate_plan_config(cfg: DictConfig) -> None:
    """``spade.plan``'s checks: the map and model files, a robot pose and a goal that differ, and a picture path
    that is none of the inputs."""
    check_paths(cfg)
    maps = map_files("map", get(cfg, "map"))
    model = input_file("model_path", get(cfg, "model_path"),
                        "pass model=PATH (a student .ckpt from python -m spade.train or its .onnx / .pt export) or set "
                        "SPADE_PLANNER_MODEL", MODEL_SUFFIXES)
    if model.suffix.lower() == ".ckpt":
        check_checkpoint("model_path", str(model), "student", "pass a student checkpoint (an expert does not plan)")
    start = point(cfg, "start", 3, "X,Y,YAW")
    goal = point(cfg, "goal", 2, "X,Y")
    if math.hypot(goal[0] - start[0], goal[1] - start[1]) < 1e-9:
        raise ConfigError(f"goal={goal[0]:g},{goal[1]:g} is the robot's own position (start); give a goal elsewhere")
    inputs = {"model_path": model, **{("map" if i == 0 else "the map's image"): p for i, p in enumerate(maps)}}
    check_bool(cfg, "overwrite")
    output_file("out", get(cfg, "out"), inputs, "set out=plan.png (a new picture file)", (".png",),
                 get(cfg, "overwrite"))
    check_bool(cfg, "planner.allow_unsigned")
    check_choice(cfg, "planner.far_goal", ["fail", "clip"])
    check_number(cfg, "planner.threshold", 0, 1, low_open=True, high_open=True)
    check_int(cfg, "planner.num_waypoints", 2)
    check_number(cfg, "picture.context_m", 0)
    check_int(cfg, "picture.width_px", 16)
