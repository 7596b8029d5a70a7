"""``python -m spade.data.verify DIR``: recompute a dataset's checksums and check shapes and value domains.

Exit status 0 when the dataset is sound, 1 with a list of problems otherwise; 2 with one ``error:`` line when
``DIR`` is no dataset at all (missing, a file, a folder without ``manifest.json``), as every entry point.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from spade.data.path_dataset import check_files, value_problems
from spade.data.format import MANIFEST, DatasetError, Manifest, read_manifest
from spade.data.packing import unpack_bits, unpack_two_bit
from spade.utils.errors import exit_on_errors

_CHUNK = 1024


def _rows(manifest: Manifest, name: str) -> np.memmap:
    spec = manifest.specs[name]
    shape = (manifest.num_instances, *spec.row_shape)
    return np.memmap(manifest.root / spec.filename, dtype=spec.dtype, mode="r", shape=shape)


def _first(indices: np.ndarray, limit: int = 5) -> str:
    shown = ", ".join(str(int(i)) for i in indices[:limit])
    return shown + (f" ... ({len(indices)} in all)" if len(indices) > limit else "")


def check_domains(manifest: Manifest) -> list[str]:
    """Value-domain checks over every instance, streamed in chunks; returns the problems found."""
    problems: list[str] = []
    n, h, w = manifest.num_instances, manifest.height, manifest.width
    if n == 0:
        return problems
    pixels = h * w
    arrays = {name: _rows(manifest, name) for name in manifest.specs}
    for lo in range(0, n, _CHUNK):
        hi = min(n, lo + _CHUNK)
        ids = np.arange(lo, hi)
        occ = unpack_two_bit(np.asarray(arrays["occupancy"][lo:hi]), pixels)
        bad = ids[(occ > 2).any(axis=1)]
        if len(bad):
            problems.append(f"occupancy: code 3 (not unknown/free/obstacle) in instances {_first(bad)}")
        channels = {c: unpack_bits(np.asarray(arrays[c][lo:hi]), pixels).reshape(-1, h, w) for c in ("start", "goal", "path")}
        for c, masks in channels.items():
            empty = ids[~masks.any(axis=(1, 2))]
            if len(empty):
                problems.append(f"{c}: empty channel in instances {_first(empty)}")
        wp = np.asarray(arrays["waypoints"][lo:hi], dtype=np.float64)
        if not np.isfinite(wp).all():  # reported by value_problems, the loaders' check
            continue
        inside = (wp[..., 0] >= -0.5) & (wp[..., 0] <= w - 0.5) & (wp[..., 1] >= -0.5) & (wp[..., 1] <= h - 0.5)
        outside = ids[~inside.all(axis=1)]
        if len(outside):
            problems.append(f"waypoints: points outside the {h} x {w} image in instances {_first(outside)}")
            continue
        for key, c, k in (("first", "start", 0), ("last", "goal", -1)):
            col = np.clip(np.rint(wp[:, k, 0]).astype(int), 0, w - 1)
            row = np.clip(np.rint(wp[:, k, 1]).astype(int), 0, h - 1)
            missed = ids[~channels[c][np.arange(hi - lo), row, col].astype(bool)]
            if len(missed):
                problems.append(f"waypoints: the {key} point lies outside the {c} disc in instances {_first(missed)}")
    return problems


def verify(root: str | Path) -> list[str]:
    """All checks of a dataset directory; returns the list of problems (empty when sound): the files, the values
    the loaders check (:func:`spade.data.path_dataset.value_problems`: NaN, inf, absurd poses, waypoints and
    alternatives) and the value domains."""
    try:
        manifest = read_manifest(root)
        check_files(manifest, checksums=True)
    except DatasetError as exc:
        return [str(exc)]
    return value_problems(manifest) + check_domains(manifest)


def check_target(root: Path) -> None:
    """The argument is an existing folder that holds a dataset manifest (else :class:`DatasetError`, one line)."""
    fix = "give a dataset folder written by python -m spade.annotate"
    if not root.exists():
        raise DatasetError(f"{root} does not exist; {fix}")
    if not root.is_dir():
        raise DatasetError(f"{root} is a file, not a dataset folder; {fix}")
    if not (root / MANIFEST).is_file():
        raise DatasetError(f"{root} holds no {MANIFEST}: it is not a SPADE dataset; {fix}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m spade.data.verify", description=__doc__.splitlines()[0])
    parser.add_argument("root", type=Path, help="dataset directory (holds manifest.json)")
    args = parser.parse_args(argv)
    exit_on_errors((DatasetError,))(check_target)(args.root)  # one line and exit status 2, as every entry point
    problems = verify(args.root)
    if problems:
        print(f"{args.root}: {len(problems)} problem(s)")
        for p in problems:
            print(f"  - {p}")
        return 1
    m = read_manifest(args.root)
    shapes = {v: int((m.label_index['shape'] == i).sum()) for i, v in enumerate(m.labels["shape"])}
    print(
        f"{args.root}: OK - {m.num_instances} instances of {m.height} x {m.width} at {m.resolution} m/px, "
        f"{len(m.labels['map_id'])} maps, {len(m.labels['scenario_id'])} scenarios, shapes {shapes}; "
        "checksums, sizes and value domains verified"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
