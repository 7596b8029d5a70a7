"""``spade.plan``'s checks: the map and model files, a robot pose and a goal that differ, a picture path that is
none of the inputs, and the planner's and the picture's options typed per config node (conf/plan.yaml)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar

from omegaconf import DictConfig

from spade.config.checkpoint_checks import check_checkpoint
from spade.config.file_checks import MODEL_SUFFIXES, input_file, map_files, output_file, point, check_paths
from spade.config.options import read_options
from spade.utils.errors import ConfigError
from spade.utils.option_checks import check_bool_value, check_choice_value, check_int_value, check_number_value


@dataclass(frozen=True)
class PlanOptions:
    """``spade.plan``'s files and flags; the files: :func:`validate_plan_config`."""

    node: ClassVar[str] = ""
    map: Any = None
    model_path: Any = None
    out: Any = None
    overwrite: bool | None = False

    def __post_init__(self) -> None:
        check_bool_value("overwrite", self.overwrite)


@dataclass(frozen=True)
class PlannerChecks:
    """The ``planner.*`` options :class:`spade.planner.Planner` reads, checked before any model is loaded."""

    node: ClassVar[str] = "planner"
    allow_unsigned: bool | None = False
    far_goal: str = "fail"
    threshold: float = 0.5
    num_waypoints: int = 64

    def __post_init__(self) -> None:
        check_bool_value("planner.allow_unsigned", self.allow_unsigned)
        check_choice_value("planner.far_goal", self.far_goal, ["fail", "clip"])
        check_number_value("planner.threshold", self.threshold, 0, 1, low_open=True, high_open=True)
        check_int_value("planner.num_waypoints", self.num_waypoints, 2)


@dataclass(frozen=True)
class PictureOptions:
    """``picture.*``: the map shown around the window and the picture's width."""

    node: ClassVar[str] = "picture"
    context_m: float = 1.0
    width_px: int = 640

    def __post_init__(self) -> None:
        check_number_value("picture.context_m", self.context_m, 0)
        check_int_value("picture.width_px", self.width_px, 16)


def validate_plan_config(cfg: DictConfig) -> PlanOptions:
    """``spade.plan``'s checks: the map and model files, a robot pose and a goal that differ, and a picture path
    that is none of the inputs; returns the command's options."""
    check_paths(cfg)
    options = read_options(cfg, PlanOptions)
    maps = map_files("map", options.map)
    model = input_file("model_path", options.model_path,
                        "pass model=PATH (a student .ckpt from python -m spade.train or its .onnx / .pt export) or set "
                        "SPADE_PLANNER_MODEL", MODEL_SUFFIXES)
    if model.suffix.lower() == ".ckpt":
        check_checkpoint("model_path", str(model), "student", "pass a student checkpoint (an expert does not plan)")
    start = point(cfg, "start", 3, "X,Y,YAW")
    goal = point(cfg, "goal", 2, "X,Y")
    if math.hypot(goal[0] - start[0], goal[1] - start[1]) < 1e-9:
        raise ConfigError(f"goal={goal[0]:g},{goal[1]:g} is the robot's own position (start); give a goal elsewhere")
    inputs = {"model_path": model, **{("map" if i == 0 else "the map's image"): p for i, p in enumerate(maps)}}
    output_file("out", options.out, inputs, "set out=plan.png (a new picture file)", (".png",), options.overwrite)
    read_options(cfg, PlannerChecks)
    read_options(cfg, PictureOptions)
    return options
