"""``spade.annotate``'s checks, before any map is loaded: the output folder, the sources, numbers, the split and the
window."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf

from spade.annotation.sketch_file import SketchFileError, load_sketch_file
from spade.annotation.sources import expand_map_specs
from spade.annotation.split import parse_split
from spade.annotation.templates import SHAPES
from spade.data.writer import check_output_dir
from spade.experiments.checks.files import _input_file, _same_file
from spade.experiments.checks.values import _check_bool, _check_choice, _check_int, _get, _unset
from spade.experiments.checks.windows import check_window_holds_manoeuvre
from spade.utils.errors import ConfigError


def validate_annotate_config(cfg: Mapping[str, Any] | DictConfig) -> None:
    """``spade.annotate``'s checks before any map is loaded: the output (never a file or a folder that is not a
    SPADE dataset, an existing dataset only with ``overwrite=true``), the sources, numbers, the split of one map
    into a training and a test part (``split``, ``split_fraction``, ``split_axis``) and the window."""
    cfg = cfg if isinstance(cfg, DictConfig) else OmegaConf.create(dict(cfg))
    if _unset(_get(cfg, "out_dir")):
        raise ConfigError("out_dir is not set; pass out_dir=FOLDER (a new folder, or a dataset with overwrite=true)")
    _check_bool(cfg, "overwrite")
    overwrite = _get(cfg, "overwrite")
    out_dir = Path(str(_get(cfg, "out_dir"))).expanduser()
    check_output_dir(out_dir, bool(overwrite))
    _check_int(cfg, "seed", 0, 2**32 - 1, fix=", e.g. seed=0")
    _check_int(cfg, "workers", 0, fix=" (0 or 1: in this process)")
    _check_choice(cfg, "start_method", ["spawn", "forkserver", "fork"])
    _check_int(cfg, "num_waypoints", 2, fix=", e.g. num_waypoints=64")
    sketches = _get(cfg, "sketches")
    rosbag = _get(cfg, "rosbag.paths")
    skipp = _get(cfg, "skipp.root")
    if not _unset(sketches):
        path = _input_file("sketches", sketches, "give a sketch file written by python -m spade.sketch (sketches.yaml)")
        if _same_file(path.parent, out_dir) or out_dir in path.parents:
            raise ConfigError(f"out_dir={out_dir} holds the input sketches={sketches}; choose another out_dir")
        try:
            load_sketch_file(path)  # parsed and validated before any map is loaded or any instance made
        except SketchFileError as exc:
            raise ConfigError(f"sketches={sketches}: {exc}") from None
    elif not _unset(rosbag):
        for item in rosbag if isinstance(rosbag, list) else [rosbag]:
            if not Path(str(item)).expanduser().exists():
                raise ConfigError(f"rosbag.paths entry {item} does not exist; give rosbag2 folders (or .mcap / .db3)")
    elif not _unset(skipp):
        if not Path(str(skipp)).expanduser().is_dir():
            raise ConfigError(f"skipp.root={skipp} is not a folder; give the folder of SKIPP's published dataset")
    else:
        _check_int(cfg, "num_instances", 1, fix=", e.g. num_instances=200")
        shapes = _get(cfg, "shape")
        for shape in shapes if isinstance(shapes, list) else [shapes]:
            if shape not in SHAPES:
                raise ConfigError(f"shape={shape!r} is not one of {list(SHAPES)}; use shape=L, shape=U or shape=[L,U]")
        try:
            expand_map_specs(_get(cfg, "maps"))
        except (ValueError, FileNotFoundError) as exc:
            raise ConfigError(f"maps={_get(cfg, 'maps')}: {exc}; give a folder of ROS map yamls, yaml paths or specs "
                              "such as warehouse:1") from None
    settings = OmegaConf.to_container(cfg, resolve=True) if isinstance(cfg, DictConfig) else dict(cfg)
    parse_split(settings)  # SplitError, a ConfigError: the key, its value and the fix in one line
    check_window_holds_manoeuvre(settings, "")
