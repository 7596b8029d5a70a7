"""Throughput of the data layer: dataset reading and dataset generation (the annotation tool), and how the
annotation tool's rate follows its worker count."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import time
from pathlib import Path
from typing import Any
from spade.annotation.pipeline import init_worker as _init_worker
from spade.annotation.run import annotate
from spade.data.settings import annotation_config


def dataset_read_throughput(root: str | Path, batch_size: int = 32) -> dict[str, Any]:
    """Open a dataset (manifest and sha256 of every file), one pass item by item, one pass through a DataLoader."""
    from torch.utils.data import DataLoader

    from spade.data.path_dataset import PathDataset

    t0 = time.perf_counter()
    dataset = PathDataset(root)
    open_s = time.perf_counter() - t0
    n = len(dataset)
    t0 = time.perf_counter()
    for i in range(n):
        dataset[i]
    item_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    for _ in DataLoader(dataset, batch_size=batch_size, num_workers=0):
        pass
    loader_s = time.perf_counter() - t0
    return {"instances": n, "image_size": list(dataset.image_size), "open_s": open_s,
            "items_per_s": n / item_s, "loader_instances_per_s": n / loader_s, "loader_batch_size": batch_size}


def generation_throughput(out_dir: str | Path, preset: str, num_instances: int | None = None,
                          window_px: int | None = None, resolution_m: float | None = None,
                          maps: str | list[str] | None = None, spacing_m: float | None = None,
                          workers: int = 1, states_per_task: int | None = None) -> dict[str, Any]:
    """Write a dataset with the annotation tool (``preset``; every other setting None: the preset's) and time it.

    Returns the instances per second and what the tool rejected: ``rejection_rates`` are fractions of the
    placement attempts (accepted scenarios plus every rejection but ``scenario_failed``).
    """
    layer: dict[str, Any] = {"workers": workers, "progress": False, "preview": {"enabled": False},
                             "num_instances": num_instances,
                             "maps": list(maps) if isinstance(maps, (list, tuple)) else maps}
    window = {k: v for k, v in (("size_px", window_px), ("resolution_m", resolution_m)) if v is not None}
    if window:
        layer["window"] = window
    if spacing_m:
        layer["instances"] = {"spacing_m": spacing_m}
    if states_per_task:
        layer["states_per_task"] = states_per_task
    cfg = annotation_config(Path(out_dir), {"preset": preset, "set": [layer]})
    t0 = time.perf_counter()
    summary = annotate(cfg)
    seconds = time.perf_counter() - t0
    rejections = dict(summary["rejections"])
    failed = rejections.pop("scenario_failed", 0)
    attempts = max(1, sum(rejections.values()) + summary["scenarios_accepted"])
    return {"preset": preset, "instances": int(summary["instances"]), "window_px": int(cfg.window.size_px),
            "resolution_m": float(cfg.window.resolution_m), "workers": workers, "seconds": seconds,
            "instances_per_s": summary["instances"] / seconds, "scenarios_accepted": summary["scenarios_accepted"],
            "scenarios_tried": summary["scenarios_tried"], "rejections": rejections,
            "rejection_rates": {k: v / attempts for k, v in rejections.items()}, "failed_scenarios": failed,
            "out_dir": str(out_dir)}


def _noop(_: int) -> int:
    return os.getpid()


def pool_startup_s(workers: int, start_method: str = "spawn") -> float:
    """Seconds to start ``workers`` annotation workers and stop them again: the process start and the imports of
    the worker's modules, with the annotation run's initializer (no maps), as every multi-worker run pays once."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    t0 = time.perf_counter()
    with ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context(start_method),
                             initializer=_init_worker, initargs=([], {}, os.getpid())) as pool:
        list(pool.map(_noop, range(workers)))
    return time.perf_counter() - t0  # the with block joins every worker it started


def dataset_digest(root: str | Path) -> str:
    """One sha256 over what a dataset holds: every array file's checksum, the labels and the run's extra
    (scenarios, rejections); the generator's settings (worker count, folder) are left out."""
    manifest = json.loads((Path(root) / "manifest.json").read_text())
    content = {"files": {k: v["sha256"] for k, v in sorted(manifest["files"].items())},
               "labels": manifest["labels"], "extra": manifest["extra"], "num_instances": manifest["num_instances"]}
    return hashlib.sha256(json.dumps(content, sort_keys=True).encode()).hexdigest()


def _cpu_s(before: os.times_result, after: os.times_result) -> float:
    """CPU seconds of this process and of its children that ended in between (the annotation workers)."""
    return sum(getattr(after, k) - getattr(before, k) for k in ("user", "system", "children_user", "children_system"))


def annotation_scaling(work: str | Path, preset: str, num_instances: int, image_sizes: list[int], workers: list[int],
                       window_m: float = 6.4, maps: str | list[str] | None = None, spacing_m: float | None = None,
                       states_per_task: int | None = None) -> list[dict[str, Any]]:
    """Annotation instances/s per worker: ``preset`` (the test preset: one map, few scenarios) written at each
    window size (``window_m`` wide) with each worker count, timed end to end.

    Each row also has the pool's start-up measured apart (:func:`pool_startup_s`), the rate without it, the CPU
    seconds of the run (this process and its workers: a figure that a machine shared with other jobs does not
    halve) and whether the dataset is the same as the first worker count's (:func:`dataset_digest`).
    """
    start_method = str(annotation_config(Path(work), {"preset": preset}).start_method)  # the runs' own
    rows: list[dict[str, Any]] = []
    for px in image_sizes:
        reference = None
        for w in workers:
            out = Path(work) / "annotation_scaling" / f"{px}px_{w}w"
            shutil.rmtree(out, ignore_errors=True)
            startup = pool_startup_s(w, start_method) if w > 1 else 0.0
            load = os.getloadavg()[0]
            before = os.times()
            row = generation_throughput(out, preset, num_instances, px, window_m / px, maps, spacing_m, w,
                                        states_per_task)
            cpu = _cpu_s(before, os.times())
            digest = dataset_digest(out)
            reference = reference or digest
            n, seconds = row["instances"], row["seconds"]
            rows.append({"preset": preset, "window_px": px, "resolution_m": row["resolution_m"], "workers": w,
                         "instances": n, "scenarios": row["scenarios_accepted"], "seconds": seconds,
                         "instances_per_s": n / seconds, "instances_per_s_per_worker": n / seconds / w,
                         "startup_s": startup,
                         "instances_per_s_per_worker_after_startup": n / max(seconds - startup, 1e-9) / w,
                         "cpu_s": cpu, "instances_per_cpu_s": n / max(cpu, 1e-9), "load_average_1m": load,
                         "dataset_sha256": digest, "same_as_first": digest == reference})
            shutil.rmtree(out, ignore_errors=True)
    return rows
