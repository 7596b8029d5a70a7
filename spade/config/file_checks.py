"""Checks of the files a command reads and writes: an input file that exists (of a model suffix), an output file
that is none of the inputs and replaces only what SPADE wrote, a map argument's files, a point given as numbers, and
the folders everything is written under (``paths.*``), which are neither empty nor the filesystem root."""

from __future__ import annotations

import math
import os
import sys
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

from hydra.experimental.callback import Callback
from omegaconf import DictConfig, OmegaConf

from spade.annotation.sources import parse_procedural
from spade.deploy.outputs import replace_refusal
from spade.config.options import read_options, resolve
from spade.maps.ros_io import MapFormatError, read_map_yaml
from spade.utils.errors import ConfigError
from spade.utils.option_checks import MISSING, is_number, unset


MODEL_SUFFIXES = (".ckpt", ".onnx", ".pt")
#: The folders every command writes under, with the fix when one is empty or the filesystem root.
PATH_KEYS = {
    "paths.root_dir": "set SPADE_HOME (or paths.root_dir) to a folder, e.g. SPADE_HOME=$HOME/spade",
    "paths.data_dir": "set paths.data_dir to a folder, or leave it unset (<SPADE_HOME>/data)",
    "paths.log_dir": "set paths.log_dir to a folder, or leave it unset (<SPADE_HOME>/logs)",
}


def _is_filesystem_root(value: Any) -> bool:
    path = Path(str(value)).expanduser()
    try:
        path = path.resolve()
    except OSError:
        return False
    return path.is_absolute() and path == Path(path.anchor)


def check_path_value(key: str, value: Any, fix: str) -> None:
    """A folder or file path a command writes at or under: not empty and not the filesystem root. An empty value
    is the worst of both: joined with the names below it (``${paths.data_dir}/tiny``) it starts at the root, so
    ``paths.data_dir=''`` would generate datasets under ``/tiny/``. None and unset values are the caller's."""
    if value is MISSING or value is None:
        return
    if not str(value).strip():
        raise ConfigError(f"{key}={str(value)!r} is an empty path: what is written under it would start at the "
                          f"filesystem root (or the current folder); {fix}")
    if _is_filesystem_root(value):
        raise ConfigError(f"{key}={value} is the filesystem root, which SPADE never writes into; {fix}")


@dataclass(frozen=True)
class PathOptions:
    """The folders every command writes under (``paths.*``): neither empty nor the filesystem root
    (:data:`PATH_KEYS`); None (unset) is the paths group's default."""

    node: ClassVar[str] = "paths"

    root_dir: Any = None
    data_dir: Any = None
    log_dir: Any = None

    def __post_init__(self) -> None:
        for key, fix in PATH_KEYS.items():
            check_path_value(key, getattr(self, key.split(".", 1)[1]), fix)


def check_paths(cfg: DictConfig) -> PathOptions:
    """:class:`PathOptions` of a command's config, built and so checked (for the checks that take the config)."""
    return read_options(cfg, PathOptions)


def same_file(a: Path, b: Path) -> bool:
    try:
        if a.exists() and b.exists():
            return os.path.samefile(a, b)
        return a.expanduser().resolve() == b.expanduser().resolve()
    except OSError:
        return False


def input_file(key: str, value: Any, fix: str, suffixes: tuple[str, ...] = ()) -> Path:
    """An input file named at ``key``: set, existing, a file (not a folder), with one of ``suffixes``."""
    if unset(value):
        raise ConfigError(f"{key} is not set; {fix}")
    path = Path(str(value)).expanduser()
    if suffixes and path.suffix.lower() not in suffixes:
        raise ConfigError(f"{key}={value} is not a model file ({' / '.join(suffixes)}); {fix}")
    if path.is_dir():
        raise ConfigError(f"{key}={value} is a directory, not a file; {fix}")
    if not path.exists():
        raise ConfigError(f"{key}={value} does not exist; {fix}")
    return path


def output_file(key: str, value: Any, inputs: Mapping[str, Path | None], fix: str,
                 suffixes: tuple[str, ...] = (), overwrite: Any = MISSING, label: str | None = None) -> Path:
    """An output file at ``key`` (given, or its default: ``label`` then names it in the messages): not empty, not
    a folder, not one of the ``inputs``, and, when it exists, replaced only with ``overwrite=true`` and only when
    SPADE wrote it (:mod:`spade.deploy.outputs`)."""
    check_path_value(key, value, fix)
    path = Path(str(value)).expanduser()
    if path.is_dir():
        raise ConfigError(f"{key}={value} is a directory; give the path of a file to write ({fix})")
    for in_key, in_path in inputs.items():
        if in_path is not None and same_file(path, in_path):
            raise ConfigError(f"{key}={value} is the input {in_key}: writing it would overwrite that file; {fix}")
    if suffixes and path.suffix.lower() not in suffixes:
        raise ConfigError(f"{key}={value} must end with {' or '.join(suffixes)}; {fix}")
    if (refusal := replace_refusal(key, path, overwrite is True, label)) is not None:
        raise ConfigError(refusal)
    check_writable(key, path, fix)
    return path


#: The most cells a map may hold, as read and after resampling to the window's metres per pixel: a grid, its costmap
#: and distance transforms take tens of bytes a cell, so 10^8 cells is already several GiB. A larger map is refused
#: in one line before it is read (a huge image raised PIL's DecompressionBombError; a 5 m/cell map resampled to
#: 0.05 m/px asked for 37 GiB).
MAX_MAP_CELLS = 100_000_000
_BYTES_PER_CELL = 40  # the grid, inflation costs, distances and the planner's arrays, roughly


def check_map_size(key: str, yaml_path: str | Path, resolution_m: float | None = None) -> None:
    """A ROS map's image has at most :data:`MAX_MAP_CELLS` pixels, and so has the map resampled to
    ``resolution_m`` (None: not resampled here); read from the image's header only."""
    from PIL import Image

    try:
        meta = read_map_yaml(yaml_path)
    except MapFormatError as exc:
        raise ConfigError(f"{key}={yaml_path}: {exc}") from None
    fix = "crop the map (or save it at a coarser resolution)"
    try:
        limit, Image.MAX_IMAGE_PIXELS = Image.MAX_IMAGE_PIXELS, None  # the header alone: no bomb to fear yet
        try:
            with Image.open(meta.image_path) as img:
                width, height = img.size
        finally:
            Image.MAX_IMAGE_PIXELS = limit
    except Exception:  # noqa: BLE001 - unreadable: the map loader names it with its own fix
        return
    if width * height > MAX_MAP_CELLS:
        raise ConfigError(f"{key}={yaml_path}: its image {meta.image_path.name} is {width} x {height} px "
                          f"({width * height / 1e6:,.0f} M cells), more than SPADE reads (at most "
                          f"{MAX_MAP_CELLS / 1e6:,.0f} M cells); {fix}")
    if resolution_m is None or not is_number(resolution_m) or resolution_m <= 0:
        return
    factor = meta.resolution / float(resolution_m)
    w, h = math.ceil(width * factor), math.ceil(height * factor)
    if w * h > MAX_MAP_CELLS:
        gib = w * h * _BYTES_PER_CELL / 2**30
        raise ConfigError(f"{key}={yaml_path}: {width} x {height} cells at {meta.resolution:g} m/cell resampled to "
                          f"{float(resolution_m):g} m/px is {w} x {h} cells (about {gib:,.0f} GiB to hold), more than "
                          f"SPADE handles (at most {MAX_MAP_CELLS / 1e6:,.0f} M cells); {fix}, or use a coarser "
                          "window.resolution_m")


def check_writable(key: str, path: str | Path, fix: str, *, is_folder: bool = False) -> None:
    """The folder a file or folder ``path`` would be written into (its nearest existing ancestor) can be written:
    a read-only folder or file system is refused in one line before any work (a ``PermissionError`` traceback at
    the end of a command before). An existing file at ``path`` must be replaceable too. ``is_folder``: ``path``
    is a folder files are written into (the folder itself, when it exists, must be writable)."""
    import tempfile

    target = Path(str(path)).expanduser()
    start = target if is_folder else target.parent
    folder = next((p for p in (start, *start.parents) if p.exists()), None)
    if folder is None or not folder.is_dir():
        return  # a file where a folder should be: the callers name it
    problem = None
    if not os.access(folder, os.W_OK | os.X_OK):
        problem = "is not writable"
    else:
        try:
            with tempfile.TemporaryFile(dir=folder):  # a read-only file system, even for root
                pass
        except OSError as exc:
            problem = f"cannot be written ({exc.strerror or exc})"
    if problem is not None:
        raise ConfigError(f"{key}={path}: the folder {folder} {problem}; {fix}")


RUN_FOLDER_FIX = ("give a folder you can write for the run's logs: paths.log_dir=DIR (or SPADE_HOME=DIR), or "
                  "hydra.run.dir=DIR")


def check_run_folder(config: DictConfig, key: str) -> None:
    """The run's log folder (Hydra's ``key``: ``hydra.run.dir``, or ``hydra.sweep.dir`` for a multirun) and
    ``paths.output_dir`` when it is given as a folder of its own: writable, before Hydra makes the folder (a
    read-only one was a ``PermissionError`` traceback from Hydra, before any check of the command)."""
    try:
        folders = [(key, OmegaConf.select(config, key, default=None))]
    except Exception:  # noqa: BLE001 - an interpolation that does not resolve: Hydra reports it as its own
        return
    paths = config.get("paths")
    if isinstance(paths, DictConfig) and "output_dir" in paths and not OmegaConf.is_interpolation(paths, "output_dir"):
        folders.append(("paths.output_dir", paths.get("output_dir")))
    for name, folder in folders:
        if not unset(folder):
            check_writable(name, str(folder), RUN_FOLDER_FIX, is_folder=True)


class RunFolderCheck(Callback):
    """Hydra callback (``conf/hydra/default.yaml``, ``conf/annotate.yaml``): :func:`check_run_folder` before the
    run's folder is made; a refusal is one ``error:`` line and exit status 2, as every user error
    (``HYDRA_FULL_ERROR=1``: the traceback instead)."""

    def on_run_start(self, config: DictConfig, **kwargs: Any) -> None:
        self._check(config, "hydra.run.dir")

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        self._check(config, "hydra.sweep.dir")

    @staticmethod
    def _check(config: DictConfig, key: str) -> None:
        try:
            check_run_folder(config, key)
        except ConfigError as exc:
            if os.environ.get("HYDRA_FULL_ERROR") == "1":
                raise
            print(f"error: {exc}", file=sys.stderr, flush=True)
            raise SystemExit(2) from None


def map_files(key: str, spec: Any) -> list[Path]:
    """The files of a map argument (a ROS yaml and its image; none for a procedural ``kind:seed``), checked."""
    fix = "give a ROS map yaml (map_server format) or a generator spec such as warehouse:101"
    if unset(spec):
        raise ConfigError(f"{key} is not set; {fix}")
    try:
        if parse_procedural(str(spec)) is not None:
            return []
    except ValueError as exc:
        raise ConfigError(f"{key}={spec}: {exc}") from None
    path = input_file(key, spec, fix)
    try:
        meta = read_map_yaml(path)
    except MapFormatError as exc:
        raise ConfigError(f"{key}={spec}: {exc}") from None
    check_map_size(key, path)
    return [path, Path(meta.image_path)]


def point(cfg: DictConfig, key: str, n: int, example: str) -> list[float]:
    """:func:`point_value` of the config's ``key`` (for the checks that take the config)."""
    return point_value(key, resolve(cfg, key), n, example)


def point_value(key: str, value: Any, n: int, example: str) -> list[float]:
    """``n`` finite numbers (a map-frame point, with a yaw for ``n`` 3) given at ``key``."""
    fix = f"pass {key}={example} (map-frame metres{', yaw in radians' if n == 3 else ''})"
    if unset(value):
        raise ConfigError(f"{key} is not set; {fix}")
    if not isinstance(value, (list, tuple)) or len(value) != n or not all(is_number(v) for v in value):
        raise ConfigError(f"{key}={value!r} is not {n} finite numbers; {fix}")
    return [float(v) for v in value]
