"""Dataset read benchmark: open a 20,000-instance 128 x 128 dataset and iterate it once in one process.

    python benchmarks/bench_dataset.py [--dataset DIR] [--instances 20000] [--size 128]

Without --dataset it first writes a dataset of that size (in a child process, so that writing does not count
towards the reader's memory) from procedurally drawn instances. Prints open time, instances/s, and resident
memory (baseline after imports, peak during the pass, and peak minus baseline).
"""

from __future__ import annotations

import argparse
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def _rss_mb() -> float:
    with open("/proc/self/statm") as handle:
        pages = int(handle.read().split()[1])
    return pages * resource.getpagesize() / 2**20


def write(root: Path, n: int, size: int, k: int) -> None:
    import numpy as np
    from skimage.draw import disk, line

    from spade.data import DatasetWriter, resample_polyline

    rng = np.random.default_rng(0)
    t0 = time.perf_counter()
    with DatasetWriter(root, image_size=size, resolution=0.05, num_waypoints=k, generator_config={"bench": n}) as w:
        for i in range(n):
            occ = rng.choice(np.array([0, 1, 2], dtype=np.uint8), size=(size, size), p=[0.2, 0.7, 0.1])
            a = rng.integers(8, size - 8, 2)
            b = rng.integers(8, size - 8, 2)
            corners = np.array([a, [a[0], b[1]], b], dtype=float)
            path = np.zeros((size, size), bool)
            for p, q in zip(corners[:-1], corners[1:]):
                path[line(int(p[1]), int(p[0]), int(q[1]), int(q[0]))] = True
            start = np.zeros_like(path)
            goal = np.zeros_like(path)
            start[disk((a[1], a[0]), 3, shape=path.shape)] = True
            goal[disk((b[1], b[0]), 3, shape=path.shape)] = True
            w.add(occ, start, goal, path, resample_polyline(corners, k), "LU"[i % 2], f"m{i % 10}", f"m{i % 10}/{i // 200}")
    print(f"wrote {n} instances in {time.perf_counter() - t0:.1f} s", flush=True)


def read(root: Path) -> None:
    import torch  # noqa: F401  (counted in the baseline, as in any training process)

    from spade.data import PathDataset

    base = _rss_mb()
    t0 = time.perf_counter()
    ds = PathDataset(root)
    t_open = time.perf_counter() - t0
    peak = base
    t0 = time.perf_counter()
    for i in range(len(ds)):
        item = ds[i]
        if i % 500 == 0:
            peak = max(peak, _rss_mb())
    elapsed = time.perf_counter() - t0
    peak = max(peak, _rss_mb(), resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)
    size = sum(p.stat().st_size for p in root.iterdir()) / 2**20
    print(f"dataset: {len(ds)} instances of {ds.image_size[0]} x {ds.image_size[1]}, {size:.0f} MiB on disk")
    print(f"open (manifest + sha256 of every file): {t_open:.2f} s")
    print(f"one pass, one process: {elapsed:.2f} s = {len(ds) / elapsed:,.0f} instances/s")
    print(f"resident memory: baseline after importing torch {base:.0f} MB, peak {peak:.0f} MB "
          f"(+{peak - base:.0f} MB for the dataset)")
    del item


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", type=Path)
    parser.add_argument("--instances", type=int, default=20_000)
    parser.add_argument("--size", type=int, default=128)
    parser.add_argument("--waypoints", type=int, default=64)
    parser.add_argument("--write-only", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.write_only:
        write(args.write_only, args.instances, args.size, args.waypoints)
        return
    if args.dataset:
        read(args.dataset)
        return
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) / "bench"
        cmd = [sys.executable, __file__, "--write-only", str(root), "--instances", str(args.instances),
               "--size", str(args.size), "--waypoints", str(args.waypoints)]
        subprocess.run(cmd, check=True)
        read(root)


if __name__ == "__main__":
    main()
