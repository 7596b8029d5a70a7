"""Throughput of the data and evaluation layers: metrics, dataset reading, dataset generation (annotation)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
import torch


def metric_throughput(instances: int, image_size: int, fid_images: int, batch: int = 64, seed: int = 0) -> dict[str, Any]:
    """APE + Hd19 (update and compute) in instances/s and FID (update of real and generated, compute) in images/s,
    on synthetic L/U paths with soft, slightly shifted predictions (:func:`spade.metrics.testing.synthetic_batch`)."""
    from scipy import ndimage

    from spade.metrics import APE, FID, HausdorffCount
    from spade.metrics.testing import synthetic_batch

    data = synthetic_batch(instances, size=image_size, num_points=64, seed=seed, width=2)
    rng = np.random.default_rng(seed)
    pred = np.stack([np.clip(ndimage.shift(ndimage.gaussian_filter(p[0], 0.8), rng.normal(0, 0.7, 2), order=1) * 2.5,
                             0, 1)[None] for p in data["path"]]).astype(np.float32)
    t = {k: torch.from_numpy(np.asarray(v)) for k, v in data.items()}
    pred_t = torch.from_numpy(pred)
    ape, hd = APE(), HausdorffCount()
    t0 = time.perf_counter()
    for i in range(0, instances, batch):
        sl = slice(i, i + batch)
        ape.update(pred_t[sl], t["state"][sl], t["waypoints"][sl], t["resolution"][sl])
        hd.update(pred_t[sl], t["path"][sl])
    a, h = ape.compute(), hd.compute()
    ape_s = time.perf_counter() - t0
    out: dict[str, Any] = {"image_size": image_size, "ape_hd_instances": instances,
                           "ape_hd_instances_per_s": instances / ape_s, "ape_cm": float(a["ape_cm"]),
                           "failures": int(a["failures"])}
    fid = FID()
    real = torch.from_numpy(synthetic_batch(fid_images, size=image_size, seed=seed + 1, width=2)["path"])
    fake = torch.from_numpy(synthetic_batch(fid_images, size=image_size, seed=seed + 2, width=2)["path"])
    t0 = time.perf_counter()
    for i in range(0, fid_images, batch):
        fid.update(real[i : i + batch], real=True)
        fid.update(fake[i : i + batch], real=False)
    computed = fid_images > fid.feature_dim
    if computed:
        out["fid"] = float(fid.compute()["fid"])
    out.update(fid_images=fid_images, fid_images_per_s=2 * fid_images / (time.perf_counter() - t0),
               fid_computed=computed, fid_extractor=fid.identity)
    return out


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


def generation_throughput(out_dir: str | Path, preset: str, num_instances: int, window_px: int, resolution_m: float,
                          maps: list[str] | None = None, spacing_m: float | None = None,
                          workers: int = 1) -> dict[str, Any]:
    """Write a dataset with the annotation tool (``preset``, a window, a number of instances) and time it."""
    from spade.annotation.run import annotate
    from spade.training.datamodule import annotation_config

    layer: dict[str, Any] = {"window": {"size_px": window_px, "resolution_m": resolution_m}, "workers": workers,
                             "progress": False, "preview": {"enabled": False}, "num_instances": num_instances}
    if maps:
        layer["maps"] = list(maps)
    if spacing_m:
        layer["instances"] = {"spacing_m": spacing_m}
    cfg = annotation_config(Path(out_dir), {"preset": preset, "set": [layer]})
    t0 = time.perf_counter()
    summary = annotate(cfg)
    seconds = time.perf_counter() - t0
    return {"preset": preset, "instances": int(summary["instances"]), "window_px": window_px,
            "resolution_m": resolution_m, "workers": workers, "seconds": seconds,
            "instances_per_s": summary["instances"] / seconds, "out_dir": str(out_dir)}
