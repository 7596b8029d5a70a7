"""Checks of a run's ``data`` and ``scale`` keys (shared by ``spade.train`` and ``spade.evaluate``): loader
numbers, dataset folders, the generation settings (window, maps, instance counts), and an existing dataset's
settings against the config's (:func:`spade.data.checks.check_dataset`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from omegaconf import DictConfig

from spade.annotation.sources import expand_map_specs
from spade.data.checks import check_dataset
from spade.data.settings import dataset_settings
from spade.config.values import check_int, check_number, folder_value, get, opt
from spade.config.file_checks import check_path_value
from spade.config.window_checks import check_window_size, check_window_holds_manoeuvre
from spade.utils.errors import ConfigError
from spade.utils.option_checks import MISSING, is_int, unset


def check_data(cfg: DictConfig) -> None:
    """The data module's options (:class:`~spade.data.datamodule_options.DataOptions`), the ``scale`` group's
    numbers, and each dataset's folder and generation settings (window, maps, instance counts) against the model."""
    from spade.config.options import DataOptions, read_options

    read_options(cfg, DataOptions)
    for key in ("image_size", "train_instances", "test_instances", "transfer_instances", "batch_size"):
        check_int(cfg, f"scale.{key}", 1, none_ok=True)
    check_number(cfg, "scale.resolution_m", 0, low_open=True, none_ok=True)
    for name in ("train", "test"):
        check_folder_path(f"data.{name}_dir", get(cfg, f"data.{name}_dir"))
        generate = get(cfg, f"data.{name}_generate")
        if generate is MISSING or generate is None:
            continue
        root = get(cfg, f"data.{name}_dir")
        settings = dataset_settings(Path(str(root)), generate)
        scaled = get(cfg, "scale.annotate") not in (MISSING, None)
        from spade.config.annotate_checks import check_annotation_settings

        check_annotation_settings(settings, f"data.{name}_generate: ")
        check_window_holds_manoeuvre(settings, "scale.annotate" if scaled else f"data.{name}_generate")
        check_window_size(cfg, settings, "scale.annotate" if scaled else f"data.{name}_generate")
        check_map_entries(cfg, name, settings.get("maps"), (settings.get("window") or {}).get("resolution_m"))
        num = settings.get("num_instances")
        if num is not None and (not is_int(num) or num < 1):
            raise ConfigError(f"data.{name}_generate num_instances={num!r} must be an integer >= 1; set "
                              f"scale.{name}_instances")


def check_datasets(cfg: DictConfig, names: tuple[str, ...] = ("train", "test")) -> None:
    """An existing dataset at ``data.train_dir`` / ``data.test_dir`` (those of ``names``) holds the config's
    generation settings (:func:`spade.data.checks.check_dataset`): a dataset is never silently reused for other
    settings; and it opens with the loaders' own checks (:func:`check_existing_dataset`), before any MLflow run:
    a truncated, edited or poisoned dataset is refused in one line without leaving a FAILED run behind."""
    for name in names:
        key = f"data.{name}_dir"
        root = folder_value(cfg, key)
        check_dataset(root, opt(cfg, f"data.{name}_generate"), key)
        if root is not None and (Path(root).expanduser() / "manifest.json").is_file():
            check_existing_dataset(key, Path(root).expanduser())


def check_existing_dataset(key: str, root: Path) -> Any:
    """The dataset at ``root`` opened as the loaders open it (:class:`~spade.data.PathDataset`: manifest and its
    checksum, every file's size and sha256, finite polylines and poses); returns it. A problem is one line naming
    ``key``, the file and the fix (:class:`~spade.data.format.DatasetError`, a user error). The hashes are
    remembered (:func:`spade.utils.hashing.file_sha256`), so the data module's own opening does not read the files
    again."""
    from spade.data import DatasetError
    from spade.data.path_dataset import PathDataset

    try:
        return PathDataset(root)
    except DatasetError as exc:
        text = str(exc).rstrip()
        if "; " not in text and ". " in text:  # "<what is wrong>; <the fix>", as every refusal reads
            what, fix = text.split(". ", 1)
            text = f"{what}; {fix[:1].lower()}{fix[1:]}"
        raise DatasetError(text if text.startswith(key) else f"{key}={root}: {text}") from None


def check_folder_path(key: str, value: Any) -> None:
    """A folder SPADE reads or creates: neither empty nor the filesystem root, and no part of its path may be an
    existing file."""
    check_path_value(key, value, f"set {key} to a folder (or paths.data_dir, which it is under by default)")
    if unset(value):
        return
    path = Path(str(value)).expanduser()
    for part in (path, *path.parents):
        if part.exists():
            if not part.is_dir():
                raise ConfigError(f"{key}={value}: {part} is a file, not a folder; set paths.data_dir (or {key}) "
                                  "to a folder")
            return


def check_map_entries(cfg: DictConfig, name: str, maps: Any, resolution_m: Any = None) -> None:
    """Every map a dataset is generated from exists (a yaml, a folder of them or a ``kind:seed`` generator spec):
    an unknown entry is named before any work, never reported as a dataset "generated with other settings"."""
    if maps is None:
        return
    try:
        specs = expand_map_specs(maps)
    except (FileNotFoundError, ValueError) as exc:
        where = "scale.train_maps" if name == "train" and get(cfg, "scale.train_maps") not in (MISSING, None) \
            else f"data.{name}_generate"
        raise ConfigError(f"{where}: {exc.args[0] if exc.args else exc}; fix that entry, e.g. warehouse:1 or the path "
                          "of a ROS map yaml (nothing was generated or changed)") from None
    from spade.annotation.sources import parse_procedural
    from spade.config.file_checks import check_map_size

    for spec in specs:
        if parse_procedural(spec) is None:
            check_map_size(f"data.{name}_generate maps", spec, resolution_m)
