"""Throughput of the data layer: dataset reading and dataset generation (the annotation tool)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any


def dataset_read_throughput(root: str | Path, batch_size: int = 32) -> dict[str, Any]:
    """Open a dataset (manifest and sha256 of every file), one pass item by item, one pass through a DataLoader."""
    from torch.utils.data import DataLoader

    from spade.data import PathDataset

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
                          workers: int = 1) -> dict[str, Any]:
    """Write a dataset with the annotation tool (``preset``; every other setting None: the preset's) and time it.

    Returns the instances per second and what the tool rejected: ``rejection_rates`` are fractions of the
    placement attempts (accepted scenarios plus every rejection but ``scenario_failed``).
    """
    from spade.annotation.run import annotate
    from spade.data.settings import annotation_config

    layer: dict[str, Any] = {"workers": workers, "progress": False, "preview": {"enabled": False},
                             "num_instances": num_instances,
                             "maps": list(maps) if isinstance(maps, (list, tuple)) else maps}
    window = {k: v for k, v in (("size_px", window_px), ("resolution_m", resolution_m)) if v is not None}
    if window:
        layer["window"] = window
    if spacing_m:
        layer["instances"] = {"spacing_m": spacing_m}
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
