"""Atomic writing of path datasets (see :mod:`spade.data.format` for the layout)."""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import socket
import time
import uuid
from pathlib import Path
from types import TracebackType
from typing import Any, BinaryIO

import numpy as np

from spade.data.format import (
    FORMAT_NAME, FORMAT_VERSION, LABEL_KEYS, MANIFEST, MANIFEST_CHECKSUM, ArraySpec, DatasetError, array_specs,
    manifest_checksum, read_manifest_json,
)
from spade.data.packing import pack_bits, pack_two_bit
from spade.utils.processes import pid_alive
from spade.maps.frame import RobotFrame


class _LabelTable:
    """Interns label strings: the manifest stores each distinct value once plus one index per instance."""

    def __init__(self) -> None:
        self.values: list[str] = []
        self.lookup: dict[str, int] = {}
        self.index: list[int] = []

    def add(self, value: str) -> None:
        value = str(value)
        if value not in self.lookup:
            self.lookup[value] = len(self.values)
            self.values.append(value)
        self.index.append(self.lookup[value])

    def to_json(self) -> dict[str, Any]:
        return {"values": self.values, "index": self.index}


class DatasetExistsError(DatasetError, FileExistsError):
    """The output is taken: a dataset appeared there (another writer finished first), or the path holds something
    that is not a SPADE dataset (which is never replaced, not even with ``overwrite=True``)."""


class DiskFullError(DatasetError, OSError):
    """The disk filled while a dataset was written; its partial folder is removed and the message says how much
    space the dataset needs."""


DATASET_EXTRAS = ("preview.png",)  # written beside the arrays (spade.annotation.preview), not in the manifest


def check_output_dir(root: str | Path, overwrite: bool, key: str = "out_dir") -> None:
    """Refuse an output folder that must not be written: an existing path that is not a SPADE dataset (a file, a
    folder without ``manifest.json``: nothing of the user's is ever replaced), or an existing dataset without
    ``overwrite``. Raises :class:`DatasetExistsError` naming ``key``, the path and the fix."""
    root = Path(root)
    if not (root.exists() or root.is_symlink()):
        return
    if not root.is_dir():
        raise DatasetExistsError(f"{key}={root} is an existing file, not a dataset folder: it is never replaced "
                                 f"(not even with overwrite=true); choose another {key}")
    if not (root / MANIFEST).is_file():
        what = "an empty folder" if not any(root.iterdir()) else "a folder that is not a SPADE dataset"
        raise DatasetExistsError(f"{key}={root} is {what} (no {MANIFEST}): overwrite=true replaces only a SPADE "
                                 f"dataset, never other files; choose another {key} (a new or dataset folder)")
    try:
        raw = read_manifest_json(root)
    except DatasetError:
        raw = {}
    if raw.get("format") != FORMAT_NAME:
        raise DatasetExistsError(f"{key}={root} holds a {MANIFEST} that is not a SPADE dataset's (format "
                                 f"{raw.get('format')!r}): it is never replaced, not even with overwrite=true; choose "
                                 f"another {key}")
    if not overwrite:
        raise DatasetExistsError(f"{key}={root} already holds a dataset; choose another {key} or pass "
                                 "overwrite=true to replace it (the old dataset is kept until the new one is complete)")
    foreign = sorted(p.name for p in root.iterdir() if p.name not in dataset_files(raw))
    if foreign:
        shown = ", ".join(foreign[:5]) + (f" and {len(foreign) - 5} more" if len(foreign) > 5 else "")
        raise DatasetExistsError(f"{key}={root} holds files its dataset does not list ({shown}): overwrite=true "
                                 f"never deletes them; move them out of the folder, or choose another {key}")


def dataset_files(manifest: dict[str, Any]) -> set[str]:
    """The names a dataset folder's own writers put there: the manifest, the array files it lists, the preview."""
    files = manifest.get("files") if isinstance(manifest.get("files"), dict) else {}
    listed = {str(entry.get("file")) for entry in files.values() if isinstance(entry, dict) and entry.get("file")}
    return {MANIFEST, *DATASET_EXTRAS, *listed}


def _free_mib(path: Path) -> str:
    try:
        st = os.statvfs(path)
        return f"{st.f_bavail * st.f_frsize / 2**20:.1f} MiB"
    except OSError:
        return "unknown"


class DatasetWriter:
    """Write a dataset into a temporary directory and rename it into place only when complete.

    Use as a context manager; call :meth:`add` once per instance. An exception inside the ``with`` block (or a
    killed process) leaves ``root`` untouched: the temporary directory never holds a manifest until every array
    file is complete, and it is renamed onto ``root`` in one step. An existing ``root`` is replaced only with
    ``overwrite=True``, only when it is a SPADE dataset (a file or any other folder is refused:
    :func:`check_output_dir`), and then only after the new dataset is complete. Without ``overwrite`` a dataset
    that another writer completed at ``root`` meanwhile is kept and this writer fails (:class:`DatasetExistsError`).
    A full disk removes the partial folder and raises :class:`DiskFullError` with the space the dataset needs.
    """

    def __init__(
        self,
        root: str | Path,
        image_size: tuple[int, int] | int,
        resolution: float,
        num_waypoints: int = 64,
        generator_config: dict[str, Any] | None = None,
        overwrite: bool = False,
        frame: dict[str, Any] | None = None,
        expected_instances: int | None = None,
        alternatives: int = 0,
        alternatives_info: dict[str, Any] | None = None,
    ) -> None:
        self.root = Path(root)
        height, width = (image_size, image_size) if isinstance(image_size, int) else tuple(image_size)
        if height <= 0 or width <= 0:
            raise ValueError(f"image_size must be positive, got {height} x {width}")
        if not resolution > 0:
            raise ValueError(f"resolution must be > 0 metres per pixel, got {resolution}")
        if num_waypoints < 2:
            raise ValueError(f"num_waypoints must be >= 2, got {num_waypoints}")
        check_output_dir(self.root, overwrite)  # a file or a non-dataset folder is never replaced
        self.overwrite = bool(overwrite)
        self.expected_instances = int(expected_instances) if expected_instances else None
        self.height, self.width = int(height), int(width)
        self.resolution = float(resolution)
        self.num_waypoints = int(num_waypoints)
        self.generator_config = json.loads(json.dumps(generator_config or {}, default=str))
        if frame is None:  # every SPADE window is in the robot frame of its side (spade.maps.frame)
            frame = RobotFrame.for_size(self.height).to_json()
        self.frame = json.loads(json.dumps(frame))
        if not 0 <= int(alternatives) <= 255:
            raise ValueError(f"alternatives must lie in 0..255 per instance, got {alternatives}")
        self.alternatives = int(alternatives)
        self.alternatives_info = dict(alternatives_info or {})
        self._alternative_counts: list[int] = []
        self.specs: dict[str, ArraySpec] = array_specs(self.height, self.width, self.num_waypoints, self.alternatives)
        self.count = 0
        self._extra: dict[str, Any] = {}
        self._labels = {key: _LabelTable() for key in LABEL_KEYS}
        self._tmp: Path | None = None
        self._files: dict[str, BinaryIO] = {}
        self._hashes: dict[str, Any] = {}

    # -- context manager -------------------------------------------------------------------------------------
    def __enter__(self) -> "DatasetWriter":
        self.root.parent.mkdir(parents=True, exist_ok=True)
        remove_stale_partials(self.root)
        self._tmp = self.root.parent / f".{self.root.name}.partial-{process_owner()}-{uuid.uuid4().hex[:8]}"
        try:
            self._tmp.mkdir()
            for name, spec in self.specs.items():
                self._files[name] = open(self._tmp / spec.filename, "wb")
                self._hashes[name] = hashlib.sha256()
        except OSError as err:
            for handle in self._files.values():
                handle.close()
            shutil.rmtree(self._tmp, ignore_errors=True)
            self._raise_disk_full(err)
            raise
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        assert self._tmp is not None
        try:
            closing_error: BaseException | None = None
            for handle in self._files.values():
                try:
                    if exc_type is None and closing_error is None:
                        handle.flush()
                        os.fsync(handle.fileno())
                    handle.close()
                except OSError as err:  # a full disk fails again on close: the folder is removed all the same
                    closing_error = closing_error or err
                    try:
                        handle.close()
                    except OSError:
                        pass
            if exc_type is None and closing_error is not None:
                raise closing_error
            if exc_type is None:
                self._finish()
        except BaseException as err:
            shutil.rmtree(self._tmp, ignore_errors=True)
            self._raise_disk_full(err)
            raise
        finally:
            if exc_type is not None:
                shutil.rmtree(self._tmp, ignore_errors=True)
        if exc is not None:
            self._raise_disk_full(exc)

    def _raise_disk_full(self, err: BaseException) -> None:
        """Re-raise a full disk (ENOSPC, EDQUOT) as :class:`DiskFullError` naming the path and the space needed."""
        import errno

        if isinstance(err, DiskFullError) or getattr(err, "errno", None) not in (errno.ENOSPC, errno.EDQUOT):
            return
        per = sum(spec.row_nbytes for spec in self.specs.values())
        written = self.count * per / 2**20
        if self.expected_instances:
            n = self.expected_instances
            need = f"the dataset needs about {n * per / 2**20:.1f} MiB ({n} instances x {per} bytes)"
        else:
            need = f"it needs {per} bytes per instance"
        raise DiskFullError(
            f"disk full while writing the dataset {self.root}: {written:.1f} MiB ({self.count} instances) were written "
            f"before the disk filled; {need}, {_free_mib(self.root.parent)} free on that filesystem. The partial "
            f"folder {self._tmp} was removed; free some space or choose another out_dir"
        ) from None

    # -- writing ---------------------------------------------------------------------------------------------
    def add(
        self,
        occupancy: np.ndarray,
        start: np.ndarray,
        goal: np.ndarray,
        path: np.ndarray,
        waypoints: np.ndarray,
        shape: str,
        map_id: str,
        scenario_id: str,
        pose: Any,
        alternatives: np.ndarray | None = None,
    ) -> int:
        """Append one instance; returns its index. Arrays are checked against the dataset's sizes.

        ``pose``: the robot's (x, y, yaw) in its map, metres and radians. ``alternatives``: (k, num_waypoints, 2)
        window pixel polylines, k <= the writer's ``alternatives`` (None: none for this instance)."""
        if self._tmp is None:
            raise RuntimeError("DatasetWriter.add must be called inside `with DatasetWriter(...) as writer:`")
        hw = (self.height, self.width)
        occupancy = np.asarray(occupancy)
        for name, arr in (("occupancy", occupancy), ("start", start), ("goal", goal), ("path", path)):
            if np.shape(arr) != hw:
                raise ValueError(f"{name} has shape {np.shape(arr)}, this dataset's instances are {hw}")
        if occupancy.dtype != np.uint8 or (occupancy.size and occupancy.max() > 2):
            raise ValueError("occupancy must be uint8 codes UNKNOWN=0 / FREE=1 / OCCUPIED=2 (see spade.maps)")
        wp = np.asarray(waypoints, dtype="<f4")
        if wp.shape != (self.num_waypoints, 2):
            raise ValueError(f"waypoints has shape {wp.shape}, expected ({self.num_waypoints}, 2)")
        if not np.isfinite(wp).all():
            raise ValueError("waypoints hold NaN or inf")
        pose_arr = np.asarray(pose, dtype="<f4").reshape(-1)
        if pose_arr.shape != (3,) or not np.isfinite(pose_arr).all():
            raise ValueError(f"pose must be three finite numbers (x, y, yaw), got {pose!r}")
        rows = {
            "occupancy": pack_two_bit(occupancy),
            "start": pack_bits(start),
            "goal": pack_bits(goal),
            "path": pack_bits(path),
            "waypoints": wp,
            "pose": pose_arr,
        }
        if self.alternatives:
            rows["alternatives"] = self._alternatives_row(alternatives)
        elif alternatives is not None and len(alternatives):
            raise ValueError("this writer stores no alternatives (construct it with alternatives=N)")
        for name, row in rows.items():
            data = np.ascontiguousarray(row).tobytes()
            self._files[name].write(data)
            self._hashes[name].update(data)
        for key, value in (("shape", shape), ("map_id", map_id), ("scenario_id", scenario_id)):
            self._labels[key].add(value)
        self.count += 1
        return self.count - 1

    def _alternatives_row(self, alternatives: np.ndarray | None) -> np.ndarray:
        row = np.full((self.alternatives, self.num_waypoints, 2), np.nan, dtype="<f4")
        alt = np.zeros((0, self.num_waypoints, 2)) if alternatives is None else np.asarray(alternatives, dtype="<f4")
        if alt.ndim != 3 or alt.shape[1:] != (self.num_waypoints, 2) or len(alt) > self.alternatives:
            raise ValueError(f"alternatives has shape {alt.shape}, expected (k <= {self.alternatives}, "
                             f"{self.num_waypoints}, 2)")
        if not np.isfinite(alt).all():
            raise ValueError("alternatives hold NaN or inf")
        row[:len(alt)] = alt
        self._alternative_counts.append(len(alt))
        return row

    def set_extra(self, key: str, value: Any) -> None:
        """Record JSON-able information in the manifest's ``extra`` section (e.g. rejection counts)."""
        self._extra[key] = json.loads(json.dumps(value, default=str))

    def _finish(self) -> None:
        assert self._tmp is not None
        files = {}
        for name, spec in self.specs.items():
            files[name] = {
                "file": spec.filename,
                "dtype": spec.dtype.str,
                "row_shape": list(spec.row_shape),
                "bytes": self.count * spec.row_nbytes,
                "sha256": self._hashes[name].hexdigest(),
            }
        manifest = {
            "format": FORMAT_NAME,
            "format_version": FORMAT_VERSION,
            "image_size": [self.height, self.width],
            "resolution": self.resolution,
            "num_waypoints": self.num_waypoints,
            "num_instances": self.count,
            "channels": {
                "state": ["occupancy (unknown 0.0 / free 0.5 / obstacle 1.0)", "start", "goal"],
                "target": ["path"],
            },
            "labels": {key: table.to_json() for key, table in self._labels.items()},
            "generator": self.generator_config,
            "frame": self.frame,
            "extra": self._extra,
            "files": files,
        }
        if self.alternatives:
            counts = np.asarray(self._alternative_counts, dtype=np.int64)
            manifest["alternatives"] = {
                **json.loads(json.dumps(self.alternatives_info, default=str)),
                "count": self.alternatives,
                "per_instance": {"min": int(counts.min()) if counts.size else 0,
                                 "mean": round(float(counts.mean()), 3) if counts.size else 0.0,
                                 "none": int((counts == 0).sum())},
            }
        manifest[MANIFEST_CHECKSUM] = manifest_checksum(json.loads(json.dumps(manifest)))  # as it will be read
        # The manifest is written last: a directory without one is never taken for a dataset.
        (self._tmp / MANIFEST).write_text(json.dumps(manifest, indent=1, sort_keys=True))
        if not self.overwrite:
            # No overwrite: one atomic rename that cannot replace a dataset another writer put there after this one
            # started (rename(2) never replaces a non-empty folder), so the first complete dataset stays.
            try:
                os.rename(self._tmp, self.root)
            except OSError as err:
                if self.root.exists():
                    raise DatasetExistsError(
                        f"out_dir={self.root}: another writer created a dataset there while this one was writing; it "
                        "is kept and this one discarded. Choose another out_dir, or pass overwrite=true to replace it"
                    ) from None
                raise err
            return
        # Overwrite: move the old dataset aside, then the new one in. A parallel writer of the same root can swap its
        # own in between: each step then fails and the swap is tried again, so every writer ends with a complete
        # dataset at root and nothing of its own left beside it.
        for attempt in range(20):
            backup = None
            if self.root.exists():
                check_output_dir(self.root, True)  # still a dataset, with nothing of the user's added meanwhile
            try:
                if self.root.exists():
                    backup = self.root.parent / f".{self.root.name}.old-{uuid.uuid4().hex[:8]}"
                    os.replace(self.root, backup)
                os.replace(self._tmp, self.root)
            except OSError:  # root vanished or reappeared meanwhile
                if backup is not None and not self.root.exists():
                    os.replace(backup, self.root)  # the old dataset back: root is never left without one
                    backup = None
                if attempt == 19:
                    raise
                time.sleep(0.01 * (attempt + 1))
                continue
            finally:
                if backup is not None:  # superseded by a complete dataset at root
                    shutil.rmtree(backup, ignore_errors=True)
            break


# -- leftovers of killed writers ---------------------------------------------------------------------------------------
LEGACY_PARTIAL_AGE_S = 3600.0  # a partial folder without an owner in its name (older SPADE) counts as stale after this


def process_owner() -> str:
    """``<host>-<pid>`` of this process, as a partial folder's name carries it."""
    return f"{re.sub(r'[^A-Za-z0-9.]', '_', socket.gethostname())}-{os.getpid()}"


def remove_stale_partials(root: str | Path) -> list[Path]:
    """Remove what killed writers left beside ``root``; returns the folders removed.

    ``.<name>.partial-<host>-<pid>-<id>`` is removed when ``<host>`` is this host and process ``<pid>`` is gone
    (a live writer of another process or host is never touched); one without an owner in its name (written by
    an older SPADE) when it is older than an hour; ``.<name>.old-<id>`` (the replaced dataset, deleted after a
    completed overwrite) when ``root`` exists.
    """
    root = Path(root)
    removed = []
    if not root.parent.is_dir():
        return removed
    host = process_owner().rsplit("-", 1)[0]
    for path in root.parent.glob(f".{root.name}.partial-*"):
        parts = path.name[len(f".{root.name}.partial-"):].rsplit("-", 2)
        if len(parts) == 3 and parts[1].isdigit():
            stale = parts[0] == host and int(parts[1]) != os.getpid() and not pid_alive(int(parts[1]))
        else:
            try:
                stale = time.time() - path.stat().st_mtime > LEGACY_PARTIAL_AGE_S
            except FileNotFoundError:
                continue
        if stale:
            shutil.rmtree(path, ignore_errors=True)
            removed.append(path)
    if root.exists():
        for path in root.parent.glob(f".{root.name}.old-*"):
            shutil.rmtree(path, ignore_errors=True)
            removed.append(path)
    return removed
