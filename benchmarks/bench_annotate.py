"""Annotation throughput: instances per second of the training presets (prints figures, asserts nothing).

    python benchmarks/bench_annotate.py                          # lshape + ushape, 10,000 each, procedural maps
    python benchmarks/bench_annotate.py --maps ../shared/maps    # the same on every real map of a folder
    python benchmarks/bench_annotate.py --num-instances 2000 --presets lshape

Target (issue): the 20,000-instance training presets in at most 10 minutes on a 2-core machine (>= 33 inst/s).
"""

from __future__ import annotations

import argparse
import os
import shutil
import tempfile
import time
from pathlib import Path

from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from spade.annotate import _alias_preset, annotate

CONF = Path(__file__).resolve().parents[1] / "conf"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--presets", nargs="+", default=["lshape", "ushape"])
    parser.add_argument("--maps", default=None, help="folder of ROS map yamls (default: the presets' procedural maps)")
    parser.add_argument("--num-instances", type=int, default=None)
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--keep", default=None, help="keep the datasets under this folder (default: temporary)")
    args = parser.parse_args()

    work = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="bench_annotate_"))
    total_n, total_s = 0, 0.0
    print(f"cpus={os.cpu_count()} workers={args.workers} maps={args.maps or 'procedural (preset)'}")
    for name in args.presets:
        overrides = [f"out_dir={work / name}", f"workers={args.workers}", "progress=false", "overwrite=true"]
        if args.maps:
            overrides.append(f"maps={args.maps}")
        if args.num_instances:
            overrides.append(f"num_instances={args.num_instances}")
        with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
            cfg = OmegaConf.to_container(compose("annotate", overrides=[*_alias_preset([f"preset={name}"]), *overrides]),
                                         resolve=True)
        t0 = time.perf_counter()
        summary = annotate(cfg)
        seconds = time.perf_counter() - t0
        n = summary["instances"]
        total_n += n
        total_s += seconds
        attempts = sum(summary["rejections"].get(k, 0) for k in summary["rejections"] if k != "scenario_failed")
        attempts += summary["scenarios_accepted"]
        rates = {k: f"{v} ({100 * v / max(attempts, 1):.1f}% of {attempts} attempts)"
                 for k, v in summary["rejections"].items() if k != "scenario_failed"}
        print(f"{name}: {n} instances in {seconds:.1f} s = {n / seconds:.1f} inst/s; scenarios accepted "
              f"{summary['scenarios_accepted']} of {summary['scenarios_tried']}; rejections {rates}; "
              f"failed scenarios {summary['rejections'].get('scenario_failed', 0)}; preview {summary['preview']}")
    print(f"TOTAL: {total_n} instances in {total_s:.1f} s = {total_n / total_s:.1f} inst/s "
          f"({total_s / 60:.2f} min; target <= 10 min for 20,000)")
    if not args.keep:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
