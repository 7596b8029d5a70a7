"""``PathDataset``: a torch Dataset over a SPADE path dataset directory, memory-mapped, never loaded whole."""

from __future__ import annotations

import mmap
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch.utils.data import Dataset

from spade.data.format import DatasetError, Manifest, read_manifest
from spade.data.packing import unpack_bits, unpack_two_bit
from spade.utils.hashing import file_sha256
from spade.data.encoding import check_encoding, marker_channels

def check_files(manifest: Manifest, checksums: bool = True) -> None:
    """Check that every array file exists with the size (and, if ``checksums``, the sha256) the manifest gives.

    Raises :class:`DatasetError` naming the file and what is wrong with it.
    """
    for name, spec in manifest.specs.items():
        entry = manifest.files[name]
        path = manifest.root / spec.filename
        expected = manifest.num_instances * spec.row_nbytes
        fix = "Re-generate the dataset (python -m spade.annotate ...) or restore the file from a copy."
        if not path.is_file():
            raise DatasetError(f"{path}: array file '{name}' is missing. {fix}")
        size = path.stat().st_size
        if size != expected or int(entry.get("bytes", expected)) != expected:
            what = "truncated" if size < expected else "longer than expected"
            raise DatasetError(f"{path}: {what}: {size} bytes, the manifest implies {expected}. {fix}")
        if checksums:
            actual = file_sha256(path)
            if actual != entry["sha256"]:
                raise DatasetError(
                    f"{path}: sha256 {actual[:12]}... differs from the manifest's {entry['sha256'][:12]}...: "
                    f"the file was altered or corrupted. {fix}"
                )


WINDOW_SPAN_LIMIT = 100
"""Window pixel coordinates (``waypoints``, ``alternatives``) may lie at most this many window sizes from the
window: a polyline of the window lies within it (``spade.data.verify`` checks that too); one 100 windows away is
no demonstration but absurd data (1e30) that would overflow the metrics late in evaluation or training."""
POSE_LIMIT_M = 1e6
"""The largest |x| or |y| of a pose, in map metres (1000 km): no occupancy map is larger, and beyond it float32
positions no longer resolve a 0.05 m pixel."""
YAW_LIMIT_RAD = 1e3
"""The largest |yaw| of a pose, in radians (a heading is an angle: a few multiples of pi at most)."""


def value_problems(manifest: Manifest) -> list[str]:
    """The arrays that are not finite, or absurd, where they must be sound: the polylines (``waypoints``), the
    poses and the alternatives (a NaN row is an empty slot, but a row is all NaN or all finite, and never inf).
    Coordinates are bounded too: window pixels within :data:`WINDOW_SPAN_LIMIT` window sizes, pose positions
    within :data:`POSE_LIMIT_M` and yaws within :data:`YAW_LIMIT_RAD`. A poisoned polyline would score any
    prediction perfectly (NaN APE counted as no error) or break the loss; checksums do not catch it when they
    were recomputed. One problem per array (its file, first bad instance and count, the fix). The one check of
    values: :class:`PathDataset` (every loader) and ``spade.data.verify`` both call it."""
    n = manifest.num_instances
    problems: list[str] = []
    if n == 0:
        return problems
    fix = "Re-generate the dataset (python -m spade.annotate ...) or restore the file from a copy."
    span = WINDOW_SPAN_LIMIT * max(manifest.height, manifest.width)
    for name in ("waypoints", "pose", "alternatives"):
        spec = manifest.specs.get(name)
        if spec is None:
            continue
        path = manifest.root / spec.filename
        values = np.memmap(path, dtype=spec.dtype, mode="r", shape=(n, *spec.row_shape))
        first, count, what = -1, 0, ""
        for start in range(0, n, 4096):
            block = np.asarray(values[start:start + 4096], dtype=np.float64)
            if name == "alternatives":
                finite = np.isfinite(block).all(axis=(-2, -1))
                empty = np.isnan(block).all(axis=(-2, -1))
                bad = ~(finite | empty).all(axis=1)
                kind = "a row that is partly NaN, or holds inf"
            else:
                bad = ~np.isfinite(block.reshape(len(block), -1)).all(axis=1)
                kind = "NaN or inf"
            if not bad.any():  # finite (or empty slots): within bounds?
                with np.errstate(invalid="ignore"):
                    if name == "pose":
                        bad = (np.abs(block[:, :2]) > POSE_LIMIT_M).any(axis=1) | (np.abs(block[:, 2]) > YAW_LIMIT_RAD)
                        kind = (f"a pose beyond {POSE_LIMIT_M:g} m from its map's origin, or a yaw beyond "
                                f"{YAW_LIMIT_RAD:g} rad")
                    else:
                        flat = np.nan_to_num(block.reshape(len(block), -1), nan=0.0)
                        bad = (np.abs(flat) > span).any(axis=1)
                        kind = (f"window pixel coordinates beyond {span:g} ({WINDOW_SPAN_LIMIT} times the "
                                f"{manifest.height} x {manifest.width} window)")
            if bad.any():
                if first < 0:
                    first, what = start + int(np.flatnonzero(bad)[0]), kind
                count += int(bad.sum())
        if first >= 0:
            problems.append(f"{path}: instance {first} holds {what} ({count} instance(s) in all): the file's values "
                            f"are not a dataset's. {fix}")
    return problems


def check_values(manifest: Manifest) -> None:
    """Raise :class:`DatasetError` with the first of :func:`value_problems` (the loaders' check)."""
    problems = value_problems(manifest)
    if problems:
        raise DatasetError(problems[0])


class PathDataset(Dataset):
    """Instances of a dataset directory as dicts of tensors.

    Each item: ``state`` float32 (3, H, W) [occupancy unknown 0 / free 0.5 / obstacle 1, start, goal];
    ``path`` float32 (1, H, W) in {0, 1}; ``waypoints`` float32 (K, 2) in pixel coordinates (x = column,
    y = row); ``pose`` float32 (3,) the robot's (x, y, yaw) in its map; ``resolution`` (metres per pixel); ``shape``, ``map_id``, ``scenario_id`` labels; ``index``; and, where the dataset
    has them, ``alternatives`` float32 (A, K, 2): alternative demonstrations, NaN rows where fewer were drawn.

    Opening checks that every file is present with the right size, and by default its sha256 (``verify=False``
    skips the hashing, e.g. in DataLoader workers). Files are memory-mapped; ``release_every`` items read in a
    row, the mapped pages are handed back to the OS so that one pass over a large dataset keeps a small
    resident set (the page cache still holds them, so re-reading stays fast).

    ``encoding`` (:mod:`spade.data.encoding`): how the start and goal channels are drawn; ``binary`` (the paper's)
    reads the stored discs, another re-draws both markers at the exact ends of the polyline (the robot, the goal).
    """

    def __init__(self, root: str | Path, verify: bool = True, release_every: int = 2048,
                 encoding: str = "binary") -> None:
        self.root = Path(root)
        self.encoding = check_encoding(encoding)
        self.manifest = read_manifest(self.root)
        check_files(self.manifest, checksums=verify)
        check_values(self.manifest)
        self.release_every = int(release_every)
        self._maps: dict[str, np.memmap] | None = None
        self._reads = 0
        self._pixels = self.manifest.height * self.manifest.width

    # -- mapping ---------------------------------------------------------------------------------------------
    def _arrays(self) -> dict[str, np.memmap]:
        if self._maps is None:
            n = self.manifest.num_instances
            self._maps = {
                name: np.memmap(self.root / spec.filename, dtype=spec.dtype, mode="r", shape=(n, *spec.row_shape))
                for name, spec in self.manifest.specs.items()
                if n > 0
            }
        return self._maps

    def release_pages(self) -> None:
        """Drop this process's resident pages of the mapped files (MADV_DONTNEED; the data stays on disk)."""
        if not self._maps or not hasattr(mmap, "MADV_DONTNEED"):
            return
        for arr in self._maps.values():
            mm = getattr(arr, "_mmap", None)
            if mm is not None:
                mm.madvise(mmap.MADV_DONTNEED)

    def __getstate__(self) -> dict[str, Any]:
        # Memory maps do not pickle; each DataLoader worker maps the files anew.
        state = self.__dict__.copy()
        state["_maps"] = None
        return state

    # -- Dataset API -----------------------------------------------------------------------------------------
    def __len__(self) -> int:
        return self.manifest.num_instances

    @property
    def image_size(self) -> tuple[int, int]:
        return self.manifest.height, self.manifest.width

    @property
    def resolution(self) -> float:
        return self.manifest.resolution

    @property
    def marker_radius_px(self) -> float:
        """The start and goal discs' radius in pixels (the annotation's ``instances.disc_radius_m``; 0.1 m when the
        manifest does not record it)."""
        radius_m = (self.manifest.generator.get("instances") or {}).get("disc_radius_m", 0.1)
        return float(radius_m) / self.manifest.resolution

    @property
    def frame(self) -> dict[str, Any]:
        """The window frame of the manifest (robot pixel, heading up; spade.maps.frame)."""
        return dict(self.manifest.frame)

    def instance_digests(self) -> list[bytes]:
        """A digest of each instance's content (its packed occupancy, start, goal and path rows): what the instance
        *is*, whatever its labels say, so that two datasets can be checked for shared windows by content."""
        import hashlib

        arrays = self._arrays()
        names = [n for n in ("occupancy", "start", "goal", "path") if n in arrays]
        return [hashlib.blake2b(b"".join(np.asarray(arrays[n][i]).tobytes() for n in names),
                                digest_size=16).digest() for i in range(len(self))]

    def labels(self, key: str) -> list[str]:
        """The per-instance values of label ``key`` ("shape", "map_id" or "scenario_id")."""
        values, index = self.manifest.labels[key], self.manifest.label_index[key]
        return [values[i] for i in index]

    def __getitem__(self, index: int) -> dict[str, Any]:
        n = len(self)
        if not -n <= index < n:
            raise IndexError(f"index {index} out of range for a dataset of {n} instances")
        index = int(index) % n
        arrays = self._arrays()
        h, w = self.manifest.height, self.manifest.width
        occupancy = unpack_two_bit(arrays["occupancy"][index], self._pixels).reshape(h, w)
        binary = unpack_bits(np.stack([arrays[c][index] for c in ("start", "goal", "path")]), self._pixels)
        state = np.empty((3, h, w), dtype=np.float32)
        np.multiply(occupancy, np.float32(0.5), out=state[0])
        waypoints = np.array(arrays["waypoints"][index], dtype=np.float32)
        if self.encoding == "binary":
            state[1:] = binary[:2].reshape(2, h, w)
        else:
            state[1:] = marker_channels(waypoints[0], waypoints[-1], h, self.marker_radius_px, self.encoding)
        path = binary[2].reshape(1, h, w).astype(np.float32)
        pose = np.array(arrays["pose"][index], dtype=np.float32)
        self._reads += 1
        if self.release_every > 0 and self._reads % self.release_every == 0:
            self.release_pages()
        m = self.manifest
        extra = {}
        if m.alternatives:
            extra["alternatives"] = torch.from_numpy(np.array(arrays["alternatives"][index], dtype=np.float32))
        return {
            "state": torch.from_numpy(state),
            "path": torch.from_numpy(path),
            "waypoints": torch.from_numpy(waypoints),
            "pose": torch.from_numpy(pose),
            "resolution": m.resolution,
            "shape": m.label("shape", index),
            "map_id": m.label("map_id", index),
            "scenario_id": m.label("scenario_id", index),
            "index": index,
            **extra,
        }
