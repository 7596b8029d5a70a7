"""``spade.annotate``'s checks, before any map is loaded: the output folder, the sources, numbers, the split and the
window."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

from omegaconf import DictConfig, OmegaConf

from spade.annotation.sketch_file import SketchFileError, load_sketch_file
from spade.annotation.sources import expand_map_specs, parse_procedural
from spade.annotation.split import parse_split
from spade.annotation.templates import SHAPES
from spade.data.writer import check_output_dir
from spade.config.file_checks import input_file, same_file, check_map_size, check_writable
from spade.config.options import read_options
from spade.config.window_checks import check_window_holds_manoeuvre
from spade.utils.errors import ConfigError
from spade.utils.option_checks import (MISSING, check_bool_value, check_choice_value, check_int_value,
                                      check_number_value, unset)


@dataclass(frozen=True)
class AnnotateOptions:
    """``spade.annotate``'s top keys (conf/annotate.yaml; the nested settings: :func:`check_annotation_settings`)."""

    node: ClassVar[str] = ""

    out_dir: Any = None
    overwrite: bool | None = False
    seed: int = 0
    workers: int = 2
    start_method: str = "spawn"
    num_waypoints: int = 64
    num_instances: int = 200
    shape: Any = "L"
    maps: Any = None
    sketches: Any = None
    rosbag: Any = None  # {paths: rosbag2 recordings}
    skipp: Any = None  # {root: SKIPP's published dataset}
    window: Any = None

    def __post_init__(self) -> None:
        if unset(self.out_dir):
            raise ConfigError("out_dir is not set; pass out_dir=FOLDER (a new folder, or a dataset with "
                              "overwrite=true)")
        check_bool_value("overwrite", self.overwrite)
        check_int_value("seed", self.seed, 0, 2**32 - 1, fix=", e.g. seed=0")
        check_int_value("workers", self.workers, 0, fix=" (0 or 1: in this process)")
        check_choice_value("start_method", self.start_method, ["spawn", "forkserver", "fork"])
        check_int_value("num_waypoints", self.num_waypoints, 2, fix=", e.g. num_waypoints=64")
        if self.source == "templates":
            check_int_value("num_instances", self.num_instances, 1, fix=", e.g. num_instances=200")
            for shape in self.shape if isinstance(self.shape, list) else [self.shape]:
                if shape not in SHAPES:
                    raise ConfigError(f"shape={shape!r} is not one of {list(SHAPES)}; use shape=L, shape=U or "
                                      "shape=[L,U]")

    @property
    def source(self) -> str:
        """Where the demonstrations come from: ``sketches``, ``rosbag``, ``skipp``, else ``templates``."""
        given = {"sketches": self.sketches, "rosbag": _setting(self.rosbag or {}, "paths"),
                 "skipp": _setting(self.skipp or {}, "root")}
        return next((name for name, value in given.items() if not unset(value)), "templates")


def validate_annotate_config(cfg: Mapping[str, Any] | DictConfig) -> AnnotateOptions:
    """``spade.annotate``'s checks before any map is loaded: the output (never a file or a folder that is not a
    SPADE dataset, an existing dataset only with ``overwrite=true``), the sources, numbers, the split of one map
    into a training and a test part (``split``, ``split_fraction``, ``split_axis``) and the window; returns the
    command's own options."""
    cfg = cfg if isinstance(cfg, DictConfig) else OmegaConf.create(dict(cfg))
    options = read_options(cfg, AnnotateOptions)
    out_dir = Path(str(options.out_dir)).expanduser()
    check_output_dir(out_dir, bool(options.overwrite))
    check_writable("out_dir", out_dir, "choose an out_dir in a folder you can write")
    sketches, rosbag, skipp = options.sketches, _setting(options.rosbag, "paths"), _setting(options.skipp, "root")
    if options.source == "sketches":
        path = input_file("sketches", sketches, "give a sketch file written by python -m spade.sketch (sketches.yaml)")
        if same_file(path.parent, out_dir) or out_dir in path.parents:
            raise ConfigError(f"out_dir={out_dir} holds the input sketches={sketches}; choose another out_dir")
        try:
            load_sketch_file(path)  # parsed and validated before any map is loaded or any instance made
        except SketchFileError as exc:
            raise ConfigError(f"sketches={sketches}: {exc}") from None
    elif options.source == "rosbag":
        for item in rosbag if isinstance(rosbag, list) else [rosbag]:
            if not Path(str(item)).expanduser().exists():
                raise ConfigError(f"rosbag.paths entry {item} does not exist; give rosbag2 folders (or .mcap / .db3)")
    elif options.source == "skipp":
        if not Path(str(skipp)).expanduser().is_dir():
            raise ConfigError(f"skipp.root={skipp} is not a folder; give the folder of SKIPP's published dataset")
    else:
        try:
            specs = expand_map_specs(options.maps)
        except (ValueError, FileNotFoundError) as exc:
            raise ConfigError(f"maps={options.maps}: {exc}; give a folder of ROS map yamls, yaml paths or specs "
                              "such as warehouse:1") from None
        for spec in specs:
            if parse_procedural(spec) is None:
                check_map_size("maps", spec, (options.window or {}).get("resolution_m"))
    settings = OmegaConf.to_container(cfg, resolve=True)
    parse_split(settings)  # SplitError, a ConfigError: the key, its value and the fix in one line
    check_annotation_settings(settings, "")
    check_window_holds_manoeuvre(settings, "")
    return options


#: The annotation settings' numbers (conf/annotate.yaml): key, (low, low_open, high, high_open, none_ok, integer).
#: A negative robot radius or inflation, a zero spacing, a probability above 1 would be written into a dataset's
#: generator record (or loop for ever); each is refused in one line before any map is loaded.
_ANNOTATION_NUMBERS: dict[str, tuple[float | None, bool, float | None, bool, bool, bool]] = {
    "robot.radius_m": (0, True, None, False, False, False),
    "robot.inflation_radius_m": (0, False, None, False, False, False),
    "robot.cost_scaling_factor": (0, True, None, False, False, False),
    "window.margin_m": (0, False, None, False, True, False),
    "template.p_mirror": (0, False, 1, False, True, False),
    "template.step_m": (0, True, None, False, True, False),
    "template.keypoint_spacing_m": (0, True, None, False, True, False),
    "scenario.goal_clearance_m": (0, False, None, False, True, False),
    "scenario.sketch_clearance_m": (0, False, None, False, True, False),
    "scenario.areas_per_map": (1, False, None, False, True, True),
    "scenario.first_index": (0, False, None, False, True, True),
    "scenario.headings_per_goal": (1, False, None, False, True, True),
    "scenario.max_attempts": (1, False, None, False, True, True),
    "scenario.max_per_map": (1, False, None, False, True, True),
    "scenario.max_failures": (1, False, None, False, True, True),
    "execution.cost_weight": (0, False, None, False, True, False),
    "execution.crop_pad_m": (0, False, None, False, True, False),
    "execution.simplify_px": (0, False, None, False, True, False),
    "execution.smoothing_px": (0, False, None, False, True, False),
    "execution.step_px": (0, True, None, False, True, False),
    "execution.max_deviation_m": (0, True, None, False, True, False),
    "execution.shape_tolerance_deg": (0, True, 180, False, True, False),
    "execution.heading_window_m": (0, True, None, False, True, False),
    "instances.spacing_m": (0, True, None, False, True, False),
    "instances.min_remaining_m": (0, False, None, False, True, False),
    "instances.disc_radius_m": (0, True, None, False, True, False),
    "alternatives.count": (0, False, 255, False, True, True),
    "alternatives.batch": (1, False, None, False, True, True),
    "alternatives.max_draws": (1, False, None, False, True, True),
    "preview.count": (0, False, None, False, True, True),
    "preview.scale": (1, False, None, False, True, True),
}


def _setting(settings: Mapping[str, Any], dotted: str) -> Any:
    node: Any = settings
    for part in dotted.split("."):
        if not isinstance(node, Mapping) or part not in node:
            return MISSING
        node = node[part]
    return node


def check_annotation_settings(settings: Mapping[str, Any], where: str) -> None:
    """The annotation settings' numbers typed and ranged (:data:`_ANNOTATION_NUMBERS`): a robot radius > 0, an
    inflation >= 0, spacings > 0, probabilities in [0, 1], counts >= 1. ``where`` prefixes the key in the message
    (``""`` for spade.annotate, ``"annotate."`` for the sketch server, ``"data.train_generate: "`` for a dataset a
    run generates)."""
    for key, (low, low_open, high, high_open, none_ok, integer) in _ANNOTATION_NUMBERS.items():
        value = _setting(settings, key)
        if value is MISSING:
            continue
        name = f"{where}{key}"
        fix = f" (conf/annotate.yaml: {key})"
        if integer:
            check_int_value(name, value, None if low is None else int(low), None if high is None else int(high),
                             none_ok=none_ok, fix=fix)
        else:
            check_number_value(name, value, low, high, low_open=low_open, high_open=high_open, none_ok=none_ok,
                                fix=fix)
