"""Print timings and statistics of the map layer: loading real ROS maps, resampling, procedural generation.

Usage: SPADE_MAPS_DIR=../shared/maps python benchmarks/bench_maps.py [--seeds 10]
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

from spade.maps import (
    GENERATORS,
    generate_map,
    largest_free_component,
    load_ros_map,
    max_clear_square_m,
    traversable_mask,
)

ROBOT_RADIUS_M = 0.22


def bench_real_maps(maps_dir: Path) -> None:
    print(f"real maps in {maps_dir}")
    header = ("map", "W x H", "m/px", "occ", "free", "unk", "load ms", "->0.05 ms", "square m")
    print("{:32s} {:>11s} {:>6s} {:>6s} {:>6s} {:>6s} {:>8s} {:>9s} {:>8s}".format(*header))
    for path in sorted(maps_dir.rglob("*.yaml")):
        t0 = time.perf_counter()
        m = load_ros_map(path)
        t1 = time.perf_counter()
        r = m.resampled(0.05)
        t2 = time.perf_counter()
        fr = m.fractions()
        print(
            f"{m.name:32s} {m.width:>5d}x{m.height:<5d} {m.resolution:6.3f} {fr['occupied']:6.3f} {fr['free']:6.3f} "
            f"{fr['unknown']:6.3f} {(t1 - t0) * 1e3:8.1f} {(t2 - t1) * 1e3:9.1f} "
            f"{max_clear_square_m(r, ROBOT_RADIUS_M):8.2f}"
        )


def bench_procedural(seeds: int) -> None:
    print(f"\nprocedural maps, default size and 0.05 m/px, seeds 0..{seeds - 1}")
    header = ("kind", "W x H", "gen ms", "occ", "free", "unk", "min square m", "min reach")
    print("{:10s} {:>9s} {:>7s} {:>6s} {:>6s} {:>6s} {:>12s} {:>9s}".format(*header))
    for kind in sorted(GENERATORS):
        times, squares, reach, fracs = [], [], [], []
        for seed in range(seeds):
            t0 = time.perf_counter()
            m = generate_map(kind, seed)
            times.append(time.perf_counter() - t0)
            squares.append(max_clear_square_m(m, ROBOT_RADIUS_M))
            trav = traversable_mask(m, ROBOT_RADIUS_M)
            reach.append(largest_free_component(m, ROBOT_RADIUS_M).sum() / max(1, trav.sum()))
            fracs.append([m.fractions()[k] for k in ("occupied", "free", "unknown")])
        f = np.mean(fracs, axis=0)
        print(
            f"{kind:10s} {m.width:>4d}x{m.height:<4d} {np.mean(times) * 1e3:7.1f} {f[0]:6.3f} {f[1]:6.3f} {f[2]:6.3f} "
            f"{min(squares):12.2f} {min(reach):9.3f}"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--seeds", type=int, default=10)
    args = parser.parse_args()
    maps_dir = os.environ.get("SPADE_MAPS_DIR")
    if maps_dir and Path(maps_dir).is_dir():
        bench_real_maps(Path(maps_dir))
    else:
        print("SPADE_MAPS_DIR not set: skipping real maps")
    bench_procedural(args.seeds)


if __name__ == "__main__":
    main()
