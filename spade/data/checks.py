"""Checks of a data config's datasets before any data is generated or read.

:func:`check_dataset` refuses an existing dataset whose generation settings differ from the ones the config asks
for (the keys that differ are named), so a dataset is never silently reused for other settings; it runs in the
data module's ``prepare_data`` and in the entry points' config checks (:mod:`spade.config`).
:func:`data_geometry` is a dataset's window geometry, read from its manifest or from the settings that will make
it. Both raise :class:`DatasetSettingsError`, a :class:`~spade.utils.errors.ConfigError` (one line, exit status 2
at the entry points) and a :class:`~spade.data.format.DatasetError`.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from spade.data.fingerprint import settings_fingerprint, shaping_settings
from spade.data.format import MANIFEST, DatasetError, read_manifest_json
from spade.data.settings import dataset_settings
from spade.utils.errors import ConfigError


class DatasetSettingsError(ConfigError, DatasetError):
    """An existing dataset made with other settings than the config asks for (or not a dataset at all)."""


def settings_difference(recorded: Mapping[str, Any], wanted: Mapping[str, Any]) -> dict[str, tuple[Any, Any]]:
    """{key: (recorded value, wanted value)} for every shaping setting that differs (missing -> None)."""
    a, b = shaping_settings(recorded), shaping_settings(wanted)
    return {k: (a.get(k), b.get(k)) for k in sorted(set(a) | set(b)) if a.get(k) != b.get(k)}


def _read_manifest_json(root: Path) -> dict[str, Any]:
    try:
        return read_manifest_json(root)
    except DatasetError as exc:  # reported as a config error: one line, exit status 2
        raise DatasetSettingsError(f"{exc} Or delete {root} to have it regenerated.") from None


def check_dataset(root: str | Path | None, generate: Any, key: str = "data.train_dir") -> None:
    """Refuse an existing dataset at ``root`` that ``generate`` (a data config's ``*_generate``) would not make.

    Missing: fine (``prepare_data`` builds it). A folder without ``manifest.json``: not a dataset (a writer never
    leaves one). A manifest whose ``generator`` records other shaping settings: the keys that differ are named,
    with both values; the dataset is never reused for settings that did not make it.
    """
    if root is None:
        return
    root = Path(str(root))
    if not root.exists():
        return
    if not (root / MANIFEST).is_file():
        raise DatasetSettingsError(
            f"{key}={root} exists but holds no {MANIFEST} (not a complete SPADE dataset): delete the folder to "
            f"have it regenerated, or point {key} at another folder"
        )
    if generate is None:
        return
    recorded = _read_manifest_json(root).get("generator") or {}
    wanted = dataset_settings(root, generate)
    diff = settings_difference(recorded, wanted)
    if diff:
        shown = "; ".join(f"{k}: dataset {a!r}, config {b!r}" for k, (a, b) in list(diff.items())[:8])
        more = f" (and {len(diff) - 8} more)" if len(diff) > 8 else ""
        raise DatasetSettingsError(
            f"{key}={root} was generated with other settings (dataset {settings_fingerprint(recorded)}, config "
            f"{settings_fingerprint(wanted)}): {shown}{more}. The dataset is kept as it is: if it is your own "
            f"(made with spade.annotate or spade.sketch), pass data=own with {key}={root} (own data is read as it is, "
            f"never regenerated); otherwise set paths.data_dir (or {key}) to another folder to generate these "
            "settings there, or change the config back to the dataset's settings"
        )


def data_geometry(root: str | Path | None, generate: Any) -> dict[str, Any] | None:
    """Window geometry of a dataset: from its manifest when it exists, else from the settings that will make it."""
    if root is None:
        return None
    root = Path(str(root))
    if (root / MANIFEST).is_file():
        manifest = _read_manifest_json(root)
        return {"image_size": manifest.get("image_size"), "resolution_m": manifest.get("resolution"),
                "frame": manifest.get("frame"), "source": str(root)}
    if generate is None:
        return None
    settings = dataset_settings(root, generate)
    size = int(settings["window"]["size_px"])
    return {"image_size": [size, size], "resolution_m": float(settings["window"]["resolution_m"]), "frame": None,
            "source": f"{root} (to be generated)"}


def split_pair_problems(train: Mapping[str, Any] | None, test: Mapping[str, Any] | None) -> list[str]:
    """Why two ``extra.split`` records are not the training and the test part of one split (empty: they are):
    both must record the same split (mode, fraction, axis and every map's line) but for the part."""
    if train is None or test is None:
        missing = [name for name, rec in (("training", train), ("test", test)) if rec is None]
        return [f"the {' and '.join(missing)} set records no split (made without split=...)"]
    problems = []
    if train.get("part") != "train":
        problems.append(f"the training set is the {train.get('part')!r} part of its split, not 'train'")
    if test.get("part") != "test":
        problems.append(f"the test set is the {test.get('part')!r} part of its split, not 'test'")
    for key in sorted((set(train) | set(test)) - {"part", "lines"}):
        if train.get(key) != test.get(key):
            problems.append(f"split {key}: training set {train.get(key)!r}, test set {test.get(key)!r}")
    lines_a, lines_b = train.get("lines") or {}, test.get("lines") or {}
    for map_id in sorted(set(lines_a) | set(lines_b)):
        a, b = lines_a.get(map_id), lines_b.get(map_id)
        if a is None or b is None:
            problems.append(f"map {map_id!r} is split in the {'test' if a is None else 'training'} set only")
            continue
        for key in ("axis", "at_m", "map_sha256"):
            if a.get(key) != b.get(key):
                problems.append(f"map {map_id!r} line {key}: training set {a.get(key)!r}, test set {b.get(key)!r}")
    return problems
