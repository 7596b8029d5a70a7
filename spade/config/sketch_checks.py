"""``spade.sketch``'s checks before the server starts: map, port, model file, output folder and window."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

from omegaconf import DictConfig

from spade.config.checkpoint_checks import check_checkpoint
from spade.config.file_checks import (
    MODEL_SUFFIXES,
    input_file,
    map_files,
    check_map_size,
    check_path_value,
    check_paths,
    check_writable,
)
from spade.config.options import read_options
from spade.config.window_checks import check_window_holds_manoeuvre
from spade.utils.errors import ConfigError
from spade.utils.option_checks import check_bool_value, check_int_value, unset
from spade.config.annotate_checks import check_annotation_settings


@dataclass(frozen=True)
class SketchOptions:
    """``spade.sketch``'s options (conf/sketch.yaml); the files they name: :func:`validate_sketch_config`."""

    node: ClassVar[str] = ""
    map: Any = None
    port: int = 8770
    host: Any = "127.0.0.1"
    allow_unsigned: bool | None = False
    model_path: Any = None
    out_dir: Any = None
    device: str = "cpu"
    models: list[str] | None = None
    allowed_hosts: list[str] | None = None
    annotate: Any = None  # overrides of conf/annotate.yaml, nested

    def __post_init__(self) -> None:
        check_int_value("port", self.port, 1, 65535, fix=", e.g. port=8770")
        if not isinstance(self.host, str) or not self.host:
            raise ConfigError(f"host={self.host!r} is not an address; use host=127.0.0.1")
        check_bool_value("allow_unsigned", self.allow_unsigned)
        for key in ("models", "allowed_hosts"):
            value = getattr(self, key)
            if value is not None and not isinstance(value, list):
                raise ConfigError(f"{key}={value!r} must be a list, e.g. {key}=[a,b]")


def validate_sketch_config(cfg: DictConfig) -> SketchOptions:
    """``spade.sketch``'s checks before the server starts: map, port, model file, output folder and window; returns
    the command's options."""
    check_paths(cfg)
    options = read_options(cfg, SketchOptions)
    files = map_files("map", options.map)
    model = options.model_path
    if not unset(model):
        path = input_file("model_path", model, "pass model=PATH: a student .ckpt or its .onnx / .pt export",
                           MODEL_SUFFIXES)
        if path.suffix.lower() == ".ckpt":
            check_checkpoint("model_path", str(path), "student",
                              "pass a student checkpoint (an expert does not plan)")
    out = options.out_dir
    check_path_value("out_dir", out, "give a folder for sketches.yaml and dataset/ (or leave out_dir unset)")
    if not unset(out) and Path(str(out)).expanduser().is_file():
        raise ConfigError(f"out_dir={out} is a file; give a folder for sketches.yaml and dataset/")
    if not unset(out):
        check_writable("out_dir", Path(str(out)).expanduser() / "sketches.yaml",
                       "give a folder you can write for sketches.yaml and dataset/")
    for folder in options.models or []:
        if not Path(str(folder)).expanduser().is_dir():
            raise ConfigError(f"models entry {folder} is not a folder; give folders that hold model files")
    # heavy: the sketching app imports its web server (FastAPI) and the annotation pipeline
    from spade.sketching.app import flatten_overrides
    from spade.sketching.workspace import annotation_config

    overrides = options.annotate
    try:
        settings = annotation_config(flatten_overrides(overrides) if isinstance(overrides, Mapping) else [])
    except Exception as exc:  # noqa: BLE001 - an override Hydra cannot apply
        raise ConfigError(f"annotate: {exc}".replace("\n", " ")) from None
    check_annotation_settings(settings, "annotate.")
    if files:
        check_map_size("map", files[0], (settings.get("window") or {}).get("resolution_m"))
    check_window_holds_manoeuvre(settings, "annotate")
    return options
