"""Checks of a run's ``data`` and ``scale`` keys (shared by ``spade.train`` and ``spade.evaluate``): loader
numbers, dataset folders, the generation settings (window, maps, instance counts), and an existing dataset's
settings against the config's (:func:`spade.data.checks.check_dataset`)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

from spade.annotation.sources import expand_map_specs, parse_procedural
from spade.config.file_checks import check_map_size, check_path_value
from spade.config.options import ModelOptions
from spade.config.window_checks import check_window_holds_manoeuvre, check_window_size
from spade.data.checks import check_dataset
from spade.data.settings import dataset_settings
from spade.utils.errors import ConfigError
from spade.utils.option_checks import check_int_value, check_number_value, is_int, unset
from spade.config.annotate_checks import check_annotation_settings
from spade.data import DatasetError


@dataclass(frozen=True)
class DataSources:
    """Where a run's datasets are (``data.<name>_dir``) and how a missing one is generated
    (``data.<name>_generate``, the annotation settings), and the teacher that labels the unlabelled states: what
    the preflight checks against the disk, the window and the checkpoints. The loader's options are
    :class:`~spade.data.datamodule_options.DataOptions`."""

    node: ClassVar[str] = "data"

    train_dir: Any = None
    test_dir: Any = None
    unlabelled_dir: Any = None
    train_generate: Mapping[str, Any] | None = None
    test_generate: Mapping[str, Any] | None = None
    unlabelled_generate: Mapping[str, Any] | None = None
    unlabelled_labels: Any = None
    unlabelled_teacher: Any = None

    def folder(self, name: str) -> str | None:
        """``data.<name>_dir`` as a folder path, None when unset."""
        value = getattr(self, f"{name}_dir")
        return None if value in (None, "") else str(value)

    def generate(self, name: str) -> Mapping[str, Any] | None:
        return getattr(self, f"{name}_generate")

    def training_sets(self) -> tuple[str, ...]:
        """The datasets a training run reads: train and test, and the unlabelled states when it has any."""
        return ("train", "test") + (("unlabelled",) if self.folder("unlabelled") is not None else ())


@dataclass(frozen=True)
class ScaleOptions:
    """The ``scale`` group's numbers: the window every dataset is cut with, instance counts and batch size."""

    node: ClassVar[str] = "scale"

    name: Any = None
    image_size: int | None = None
    resolution_m: float | None = None
    train_instances: int | None = None
    test_instances: int | None = None
    transfer_instances: int | None = None
    batch_size: int | None = None
    annotate: Any = None  # the annotation settings the scale sets for every dataset (its key in refusals)
    train_maps: Any = None

    def __post_init__(self) -> None:
        for key in ("image_size", "train_instances", "test_instances", "transfer_instances", "batch_size"):
            check_int_value(f"scale.{key}", getattr(self, key), 1, none_ok=True)
        check_number_value("scale.resolution_m", self.resolution_m, 0, low_open=True, none_ok=True)


def check_data(sources: DataSources, scale: ScaleOptions, model: ModelOptions | None) -> None:
    """Each dataset's folder and generation settings (window, maps, instance counts) against the scale and the
    model (the loader's and the scale's own numbers are checked by their options)."""
    for name in ("train", "test"):
        check_folder_path(f"data.{name}_dir", getattr(sources, f"{name}_dir"))
        generate = sources.generate(name)
        if generate is None:
            continue
        settings = dataset_settings(Path(str(getattr(sources, f"{name}_dir"))), generate)
        key = "scale.annotate" if scale.annotate is not None else f"data.{name}_generate"
        check_annotation_settings(settings, f"data.{name}_generate: ")
        check_window_holds_manoeuvre(settings, key)
        check_window_size(scale, model, settings, key)
        check_map_entries(scale, name, settings.get("maps"), (settings.get("window") or {}).get("resolution_m"))
        num = settings.get("num_instances")
        if num is not None and (not is_int(num) or num < 1):
            raise ConfigError(f"data.{name}_generate num_instances={num!r} must be an integer >= 1; set "
                              f"scale.{name}_instances")


def check_datasets(sources: DataSources, names: tuple[str, ...] = ("train", "test")) -> None:
    """An existing dataset at ``data.train_dir`` / ``data.test_dir`` (those of ``names``) holds the config's
    generation settings (:func:`spade.data.checks.check_dataset`): a dataset is never silently reused for other
    settings; and it opens with the loaders' own checks (:func:`check_existing_dataset`), before any MLflow run:
    a truncated, edited or poisoned dataset is refused in one line without leaving a FAILED run behind."""
    for name in names:
        key = f"data.{name}_dir"
        root = sources.folder(name)
        check_dataset(root, sources.generate(name), key)
        if root is not None and (Path(root).expanduser() / "manifest.json").is_file():
            check_existing_dataset(key, Path(root).expanduser())


def check_existing_dataset(key: str, root: Path) -> Any:
    """The dataset at ``root`` opened as the loaders open it (:class:`~spade.data.PathDataset`: manifest and its
    checksum, every file's size and sha256, finite polylines and poses); returns it. A problem is one line naming
    ``key``, the file and the fix (:class:`~spade.data.format.DatasetError`, a user error). The hashes are
    remembered (:func:`spade.utils.hashing.file_sha256`), so the data module's own opening does not read the files
    again."""
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


def check_map_entries(scale: ScaleOptions, name: str, maps: Any, resolution_m: Any = None) -> None:
    """Every map a dataset is generated from exists (a yaml, a folder of them or a ``kind:seed`` generator spec):
    an unknown entry is named before any work, never reported as a dataset "generated with other settings"."""
    if maps is None:
        return
    try:
        specs = expand_map_specs(maps)
    except (FileNotFoundError, ValueError) as exc:
        where = "scale.train_maps" if name == "train" and scale.train_maps is not None else f"data.{name}_generate"
        raise ConfigError(f"{where}: {exc.args[0] if exc.args else exc}; fix that entry, e.g. warehouse:1 or the path "
                          "of a ROS map yaml (nothing was generated or changed)") from None
    for spec in specs:
        if parse_procedural(spec) is None:
            check_map_size(f"data.{name}_generate maps", spec, resolution_m)
