"""The on-disk layout of a SPADE path dataset and the validation of its manifest.

A dataset is one directory::

    manifest.json    format version, image size, metres per pixel, counts, per-instance labels,
                     the generator's full config, and the size and sha256 of every array file
    occupancy.bin    uint8 (N, ceil(H*W/4)): occupancy codes, 2 bits per pixel (see spade.data.packing)
    start.bin        uint8 (N, ceil(H*W/8)): start disc, 1 bit per pixel
    goal.bin         uint8 (N, ceil(H*W/8)): goal disc, 1 bit per pixel
    path.bin         uint8 (N, ceil(H*W/8)): remaining path, 1 bit per pixel
    waypoints.bin    float32 (N, K, 2): ground-truth polyline in pixel coordinates (x = column, y = row)
    pose.bin         float32 (N, 3): the robot's pose in its map, (x, y, yaw) in metres and radians
    alternatives.bin optional, float32 (N, A, K, 2): up to A alternative demonstrations of each instance in its
                     window (x, y pixels), NaN rows where an instance has fewer
                     (spade.annotation.alternative_demonstrations); the manifest's ``alternatives`` section says
                     how they were drawn

Version 2: every window is in the robot's frame (``frame`` in the manifest: the robot's pixel and "heading up",
see spade.maps.frame), so a prediction maps back to map metres through the instance's pose. Version 1
windows were axis-aligned and hid the heading; they are refused with the command that rebuilds them.

Array files are raw C-order arrays whose shapes follow from the manifest, so that readers memory-map them.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from spade.data.packing import bit_nbytes, two_bit_nbytes
from spade.utils.errors import UserError

FORMAT_NAME = "spade-path-dataset"
FORMAT_VERSION = 2
MANIFEST = "manifest.json"
# The manifest's own checksum: the sha256 of the rest of it as canonical JSON. A field edited after writing (the
# resolution rescales every cm metric) is refused, not verified; so is a manifest without it (deleting the field
# would otherwise pass any edit): every manifest the writer has published since carries one.
MANIFEST_CHECKSUM = "manifest_sha256"


def manifest_checksum(raw: dict[str, Any]) -> str:
    """The sha256 of a manifest without its :data:`MANIFEST_CHECKSUM` field, as canonical JSON (sorted keys)."""
    body = {k: v for k, v in raw.items() if k != MANIFEST_CHECKSUM}
    return hashlib.sha256(json.dumps(body, sort_keys=True).encode()).hexdigest()
LABEL_KEYS = ("shape", "map_id", "scenario_id")
BINARY_CHANNELS = ("start", "goal", "path")


class DatasetError(UserError, RuntimeError):
    """A dataset directory that is missing, incomplete, corrupt or of another format."""


class ManifestMissingError(DatasetError, FileNotFoundError):
    """A dataset path without ``manifest.json`` (a writer publishes it last: an interrupted write leaves none)."""


class ManifestFormatError(DatasetError, ValueError):
    """A ``manifest.json`` that cannot be read as a JSON object."""


@dataclass(frozen=True)
class ArraySpec:
    """One array file: its name, element type and the shape of one instance's row."""

    name: str
    dtype: np.dtype
    row_shape: tuple[int, ...]

    @property
    def filename(self) -> str:
        return f"{self.name}.bin"

    @property
    def row_nbytes(self) -> int:
        return int(np.prod(self.row_shape)) * self.dtype.itemsize


def array_specs(height: int, width: int, num_waypoints: int, alternatives: int = 0) -> dict[str, ArraySpec]:
    """The array files of a dataset with instances of ``height`` x ``width`` and ``num_waypoints`` points (and, with
    ``alternatives`` > 0, up to that many alternative demonstrations per instance)."""
    pixels = height * width
    specs = [ArraySpec("occupancy", np.dtype(np.uint8), (two_bit_nbytes(pixels),))]
    specs += [ArraySpec(name, np.dtype(np.uint8), (bit_nbytes(pixels),)) for name in BINARY_CHANNELS]
    specs.append(ArraySpec("waypoints", np.dtype("<f4"), (num_waypoints, 2)))
    specs.append(ArraySpec("pose", np.dtype("<f4"), (3,)))
    if alternatives > 0:
        specs.append(ArraySpec("alternatives", np.dtype("<f4"), (int(alternatives), num_waypoints, 2)))
    return {s.name: s for s in specs}


@dataclass(frozen=True)
class Manifest:
    """The parsed and validated ``manifest.json`` of a dataset."""

    root: Path
    height: int
    width: int
    resolution: float
    num_waypoints: int
    num_instances: int
    labels: dict[str, tuple[str, ...]]
    label_index: dict[str, np.ndarray]
    files: dict[str, dict[str, Any]]
    generator: dict[str, Any]
    extra: dict[str, Any]
    frame: dict[str, Any]
    alternatives: int = 0  # alternative demonstrations stored per instance (0: none; older datasets)
    alternatives_info: dict[str, Any] | None = None  # how they were drawn (the manifest's ``alternatives``)

    @property
    def specs(self) -> dict[str, ArraySpec]:
        return array_specs(self.height, self.width, self.num_waypoints, self.alternatives)

    def label(self, key: str, index: int) -> str:
        return self.labels[key][int(self.label_index[key][index])]


def _require(cond: bool, path: Path, what: str) -> None:
    if not cond:
        raise DatasetError(f"{path}: {what}. Re-generate the dataset (python -m spade.annotate ...) or restore it.")


def read_manifest_json(root: str | Path) -> dict[str, Any]:
    """The JSON object of ``root/manifest.json``, not validated: the one place a manifest file is parsed.

    :func:`read_manifest` validates it; the config checks and the MLflow tracking read single fields of it
    (``generator``, ``image_size``, ``labels`` ...). Raises :class:`ManifestMissingError` (also a
    ``FileNotFoundError``) or :class:`ManifestFormatError` (also a ``ValueError``), naming the file.
    """
    path = Path(root) / MANIFEST
    try:
        raw = json.loads(path.read_text())
    except FileNotFoundError as exc:
        raise ManifestMissingError(
            f"{path}: no dataset manifest (manifest.json is missing; an interrupted write leaves none). Re-generate "
            "the dataset (python -m spade.annotate ...) or restore it."
        ) from exc
    except (OSError, ValueError) as exc:
        raise ManifestFormatError(f"{path}: cannot be parsed as JSON ({exc}). Re-generate the dataset.") from exc
    if not isinstance(raw, dict):
        raise ManifestFormatError(f"{path}: not a {FORMAT_NAME} manifest (not a JSON object). Re-generate the dataset "
                                  "(python -m spade.annotate ...) or restore it.")
    return raw


def _check_generator_record(raw: dict[str, Any], path: Path, height: int, width: int, resolution: float,
                            num_waypoints: int) -> None:
    """The manifest's geometry agrees with its own ``generator`` record and window frame, where they state it."""
    generator = raw.get("generator") if isinstance(raw.get("generator"), dict) else {}
    window = generator.get("window") if isinstance(generator.get("window"), dict) else {}

    def number(value: Any) -> float | None:
        return float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else None

    # an import (SKIPP layout, rosbag) keeps its recording's resolution: the window's records only what was drawn
    drawn = (raw.get("extra") or {}).get("source") in ("templates", "sketches")
    pairs = [("resolution", resolution, "generator.window.resolution_m",
              number(window.get("resolution_m")) if drawn else None),
             ("image_size", width, "generator.window.size_px", number(window.get("size_px"))),
             ("num_waypoints", num_waypoints, "generator.num_waypoints", number(generator.get("num_waypoints"))),
             ("image_size", width, "frame.size_px", number((raw.get("frame") or {}).get("size_px")))]
    for key, value, where, recorded in pairs:
        _require(recorded is None or abs(recorded - value) <= 1e-9 * max(1.0, abs(value)), path,
                 f"{key} {value} disagrees with {where} {recorded:g} (the manifest was edited, or written by a "
                 "broken writer)" if recorded is not None else "")
    _require(window.get("size_px") is None or height == width, path, f"image_size {height} x {width} is not square, "
             "but the generator's windows are")


def _check_manifest_checksum(raw: dict[str, Any], path: Path) -> None:
    """The manifest carries its :data:`MANIFEST_CHECKSUM` and it matches the rest: an edited field (the resolution
    rescales every cm metric) is refused, and so is a manifest whose checksum was deleted along with the edit."""
    stated = raw.get(MANIFEST_CHECKSUM)
    _require(stated is not None, path,
             f"the manifest has no {MANIFEST_CHECKSUM} (it was deleted, or the dataset was written before SPADE "
             "checksummed its manifests), so its fields cannot be trusted")
    _require(stated == manifest_checksum(raw), path,
             f"the manifest was changed after it was written ({MANIFEST_CHECKSUM} does not match its content; a "
             "field such as resolution would rescale every metric)")


def read_manifest(root: str | Path) -> Manifest:
    """Read and validate ``root/manifest.json``; raise :class:`DatasetError` naming the problem."""
    root = Path(root)
    path = root / MANIFEST
    if not root.is_dir():
        raise DatasetError(
            f"{root}: no such dataset directory. Create one with `python -m spade.annotate out_dir={root}`."
        )
    _require(path.is_file(), path, "manifest.json is missing (an interrupted write leaves no manifest)")
    raw = read_manifest_json(root)
    _require(raw.get("format") == FORMAT_NAME, path, f"not a {FORMAT_NAME} manifest")
    version = raw.get("format_version")
    if version == 1:
        raise DatasetError(
            f"{path}: format_version 1 (axis-aligned windows that hide the robot's heading); this SPADE reads "
            f"version {FORMAT_VERSION} (robot-frame windows). Delete {root} and rebuild it: spade.train rebuilds "
            f"a missing dataset by itself, or run `python -m spade.annotate out_dir={root} ...` with its settings "
            "(the old manifest's `generator` section lists them)."
        )
    _require(version == FORMAT_VERSION, path, f"format_version {version!r}, this SPADE reads {FORMAT_VERSION}")
    try:
        height, width = (int(v) for v in raw["image_size"])
        resolution = float(raw["resolution"])
        num_waypoints = int(raw["num_waypoints"])
        count = int(raw["num_instances"])
        labels_raw = raw["labels"]
        files = raw["files"]
    except (KeyError, TypeError, ValueError) as exc:
        raise DatasetError(f"{path}: a required field is missing or malformed ({exc!r}). Re-generate it.") from exc
    _check_manifest_checksum(raw, path)
    _require(height > 0 and width > 0, path, f"image_size must be positive, got {height} x {width}")
    _require(resolution > 0, path, f"resolution must be > 0 m/px, got {resolution}")
    _require(num_waypoints >= 2, path, f"num_waypoints must be >= 2, got {num_waypoints}")
    _require(count >= 0, path, f"num_instances must be >= 0, got {count}")
    labels: dict[str, tuple[str, ...]] = {}
    index: dict[str, np.ndarray] = {}
    for key in LABEL_KEYS:
        entry = labels_raw.get(key) if isinstance(labels_raw, dict) else None
        _require(isinstance(entry, dict), path, f"labels.{key} is missing")
        values = tuple(str(v) for v in entry.get("values", []))
        idx = np.asarray(entry.get("index", []), dtype=np.int64)
        _require(idx.shape == (count,), path, f"labels.{key}.index has {idx.size} entries for {count} instances")
        _require(
            count == 0 or (idx.min() >= 0 and idx.max() < len(values)), path, f"labels.{key}.index out of range"
        )
        labels[key], index[key] = values, idx
    frame = raw.get("frame")
    _require(isinstance(frame, dict) and frame.get("kind") == "robot", path,
             "the window frame (frame.kind = robot) is missing")
    alt_info = raw.get("alternatives")
    alternatives = 0
    if alt_info is not None:
        _require(isinstance(alt_info, dict) and isinstance(alt_info.get("count"), int) and alt_info["count"] > 0
                 and isinstance(files, dict) and "alternatives" in files, path,
                 "the alternatives section is malformed (it needs a positive count and files.alternatives)")
        alternatives = int(alt_info["count"])
    for name, spec in array_specs(height, width, num_waypoints, alternatives).items():
        entry = files.get(name)
        _require(isinstance(entry, dict) and "sha256" in entry, path, f"files.{name} is missing")
        recorded = entry.get("row_shape")
        _require(recorded is None or [int(v) for v in recorded] == list(spec.row_shape), path,
                 f"files.{name}.row_shape {recorded} does not fit image_size {height} x {width} and num_waypoints "
                 f"{num_waypoints} (expected {list(spec.row_shape)})")
    _check_generator_record(raw, path, height, width, resolution, num_waypoints)
    return Manifest(
        root=root,
        height=height,
        width=width,
        resolution=resolution,
        num_waypoints=num_waypoints,
        num_instances=count,
        labels=labels,
        label_index=index,
        files=files,
        generator=dict(raw.get("generator") or {}),
        extra=dict(raw.get("extra") or {}),
        frame=dict(frame),
        alternatives=alternatives,
        alternatives_info=dict(alt_info) if alternatives else None,
    )
