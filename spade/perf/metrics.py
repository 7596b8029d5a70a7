"""The metrics: APE + Hd19 and FID throughput, a per-instance reference pipeline timed on the same predictions,
how FID follows controlled degradations and shape changes, and FID's table on a real test set (the ``metrics``
section of ``python -m spade.bench``).

The throughput and degradation measurements run on :mod:`spade.metrics.synthetic`: L/U ground-truth paths
(``synthetic_batch``) and plausible soft predictions of them (``synthetic_predictions``: blurred, shifted, noisy,
some with stray blobs, gaps or nothing predicted). FID's shape validity (:func:`shape_validity`) runs on
robot-frame L/U paths (:mod:`spade.metrics.shape_paths`), and :func:`fid_test_table` on a dataset directory
(``metrics.fid_test_dir=``).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from spade.metrics.ape import APE
from spade.metrics.extraction import marker_centre
from spade.metrics.features import RandomConvFeatures, build_feature_extractor
from spade.metrics.fid import FID
from spade.metrics.hausdorff import HausdorffCount
from spade.metrics.shape_features import ShapeFeatures
from spade.metrics.synthetic import degrade, synthetic_batch, synthetic_predictions
from spade.data.path_dataset import PathDataset
from spade.data.polyline import resample_polyline
from spade.metrics.baselines import BASELINES, baseline_polylines, draw_polyline
from spade.metrics.shape_paths import render_paths, rotate_paths, sample_paths, straight_paths

SENSITIVITY_LEVELS = {"shift": [0, 1, 2, 4, 8], "blur": [0, 0.5, 1, 2, 3], "dropout": [0, 0.1, 0.2, 0.4, 0.6],
                      "blobs": [0, 1, 2, 4, 8]}


def predicted_paths(instances: int, image_size: int, seed: int = 0) -> dict[str, np.ndarray]:
    """Ground truth (state, path, waypoints, resolution at 0.05 m/px) and soft predictions (``pred``) of it."""
    data = synthetic_batch(instances, size=image_size, num_points=64, seed=seed, width=2, resolution=0.05)
    data["pred"] = synthetic_predictions(data["path"], seed=seed + 1)
    return data


def _ape_hd(data: dict[str, np.ndarray], batch: int) -> tuple[float, dict[str, float], HausdorffCount]:
    """Seconds of APE + Hd19 update and compute over ``data``, their values, and the Hd19 metric (per instance)."""
    t = {k: torch.from_numpy(np.asarray(v)) for k, v in data.items()}
    ape, hd = APE(), HausdorffCount()
    t0 = time.perf_counter()
    for i in range(0, len(t["pred"]), batch):
        sl = slice(i, i + batch)
        ape.update(t["pred"][sl], t["state"][sl], t["waypoints"][sl], t["resolution"][sl])
        hd.update(t["pred"][sl], t["path"][sl])
    values = {**ape.compute(), **hd.compute()}
    return time.perf_counter() - t0, {k: float(v) for k, v in values.items()}, hd


def metric_throughput(instances: int, image_size: int, fid_images: int, batch: int = 64, seed: int = 0,
                      reference_instances: int = 0, loops_instances: int = 0) -> dict[str, Any]:
    """APE + Hd19 (update and compute) in instances/s and FID (update of real and generated, compute) in images/s.

    With ``reference_instances``, the first that many predictions also go through :func:`reference_instance`
    (timed: ``reference``, with the speed-up and the agreement of the values); with ``loops_instances``, through
    its variant with SKIPP's literal Python adjacency loops (``reference_loops``). The reference needs ``evo``
    (the dev extra); without it ``reference`` says it was skipped.
    """
    data = predicted_paths(instances, image_size, seed)
    seconds, values, hd = _ape_hd(data, batch)
    out: dict[str, Any] = {"image_size": image_size, "ape_hd_instances": instances, "ape_hd_seconds": seconds,
                           "ape_hd_instances_per_s": instances / seconds, "ape_cm": values["ape_cm"],
                           "failures": int(values["failures"]), "values": values}
    per_ours = seconds / instances
    m = min(int(reference_instances), instances)
    if m > 0 or loops_instances > 0:
        try:
            import evo  # noqa: F401
        except ImportError:
            out["reference"] = {"skipped": "evo is not installed (pip install evo, or the dev extra)"}
            m, loops_instances = 0, 0
    if m > 0:
        ref_s, ref_ape, ref_hd = reference(data, m)
        ours_hd = hd.per_instance().numpy()[:m]
        ref_hd = np.array(ref_hd)
        both = np.isfinite(ours_hd) & np.isfinite(ref_hd)
        _, sub, _ = _ape_hd({k: v[:m] for k, v in data.items()}, batch)
        ok = np.array([v is not None for v in ref_ape])
        ref_vals = np.array([v for v in ref_ape if v is not None], dtype=float)
        out["reference"] = {
            "instances": m, "seconds": ref_s, "ms_per_instance": ref_s / m * 1e3, "speedup": ref_s / m / per_ours,
            "hd_max_abs_diff_px": float(np.abs(ours_hd[both] - ref_hd[both]).max()) if both.any() else 0.0,
            "hd_empty_flags_equal": bool((np.isinf(ours_hd) == np.isinf(ref_hd)).all()),
            "ape_mean_cm": float(ref_vals.mean()) if ref_vals.size else float("nan"),
            "ape_median_cm": float(np.median(ref_vals)) if ref_vals.size else float("nan"),
            "failures": int(m - ok.sum()), "ours_ape_mean_cm": sub["ape_cm"],
            "ours_ape_median_cm": sub["ape_median_cm"], "ours_failures": int(sub["failures"])}
    n_loops = min(int(loops_instances), instances)
    if n_loops > 0:
        loop_s, _, _ = reference(data, n_loops, loops=True)
        out["reference_loops"] = {"instances": n_loops, "ms_per_instance": loop_s / n_loops * 1e3,
                                  "slowdown": loop_s / n_loops / per_ours}
    out.update(fid_throughput(fid_images, image_size, batch, seed))
    return out


def fid_throughput(images: int, image_size: int, batch: int = 64, seed: int = 0) -> dict[str, Any]:
    """FID of ``images`` synthetic paths against as many independently drawn ones blurred (sigma 0.7): update and
    compute times; computed only with more images than the extractor has features."""
    real = torch.from_numpy(synthetic_batch(images, size=image_size, seed=seed + 11, width=2)["path"])
    fake = torch.from_numpy(degrade(synthetic_batch(images, size=image_size, seed=seed + 12, width=2)["path"],
                                    "blur", 0.7))
    fid = FID()
    t0 = time.perf_counter()
    for i in range(0, images, batch):
        fid.update(real[i : i + batch], real=True)
        fid.update(fake[i : i + batch], real=False)
    update_s = time.perf_counter() - t0
    out: dict[str, Any] = {"fid_images": images, "fid_update_s": update_s, "fid_extractor": fid.identity,
                           "fid_feature_dim": fid.feature_dim, "fid_computed": images > fid.feature_dim}
    if out["fid_computed"]:
        out["fid"] = float(fid.compute()["fid"])
    out["fid_compute_s"] = time.perf_counter() - t0 - update_s
    out["fid_images_per_s"] = 2 * images / (time.perf_counter() - t0)
    return out


def reference_instance(pred: np.ndarray, truth_mask: np.ndarray, start: np.ndarray, goal: np.ndarray,
                       waypoints: np.ndarray, resolution: float, loops: bool = False) -> tuple[float | None, float]:
    """One instance the straightforward way: thin, dense pixel adjacency matrix, all-pairs shortest paths,
    resample, evo's APE (cm; None when no path is found); scipy's directed_hausdorff both ways (px).

    ``loops``: fill the adjacency matrix with a Python double loop over pixel pairs, literally as SKIPP's
    ``find_longest_path`` does (otherwise numpy broadcasting, which is kinder to the reference).
    """
    from evo.core import metrics as evo_metrics
    from evo.core.trajectory import PosePath3D
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import shortest_path
    from scipy.spatial.distance import directed_hausdorff
    from skimage.morphology import thin

    mask = pred >= 0.5
    hd = float("inf")
    if mask.any():
        a, b = np.argwhere(mask).astype(float), np.argwhere(truth_mask > 0.5).astype(float)
        hd = max(directed_hausdorff(a, b)[0], directed_hausdorff(b, a)[0])
    pts = np.argwhere(thin(mask))[:, ::-1].astype(float)  # (x, y)
    if len(pts) < 2:
        return None, hd
    if loops:
        adj = np.zeros((len(pts), len(pts)))
        for i, (x1, y1) in enumerate(pts):
            for j, (x2, y2) in enumerate(pts):
                if i != j and abs(x1 - x2) <= 1 and abs(y1 - y2) <= 1:
                    adj[i, j] = np.hypot(x1 - x2, y1 - y2)
    else:
        diff = np.abs(pts[:, None, :] - pts[None, :, :]).max(axis=2)
        adj = np.where(diff == 1, np.linalg.norm(pts[:, None, :] - pts[None, :, :], axis=2), 0.0)
    dist, pred_idx = shortest_path(csr_matrix(adj), directed=False, return_predecessors=True)
    s = int(np.argmin(np.linalg.norm(pts - start, axis=1)))
    reachable = np.flatnonzero(np.isfinite(dist[s]))
    g = int(reachable[np.argmin(np.linalg.norm(pts[reachable] - goal, axis=1))])
    if g == s:
        return None, hd
    order = [g]
    while order[-1] != s:
        order.append(int(pred_idx[s, order[-1]]))
    chain = pts[order[::-1]]
    k = len(waypoints)

    def path(p: np.ndarray) -> PosePath3D:
        xyz = np.column_stack([resample_polyline(p, k), np.zeros(k)])
        return PosePath3D(positions_xyz=xyz, orientations_quat_wxyz=np.tile([1.0, 0, 0, 0], (k, 1)))

    metric = evo_metrics.APE(evo_metrics.PoseRelation.translation_part)
    metric.process_data((path(waypoints), path(chain)))
    return metric.get_statistic(evo_metrics.StatisticsType.mean) * resolution * 100, hd


def reference(data: dict[str, np.ndarray], n: int, loops: bool = False) -> tuple[float, list, list]:
    """Seconds, APEs and Hausdorff distances of :func:`reference_instance` over the first ``n`` predictions."""
    apes, hds = [], []
    t0 = time.perf_counter()
    for i in range(n):
        a, h = reference_instance(data["pred"][i, 0], data["path"][i, 0], marker_centre(data["state"][i, 1]),
                                  marker_centre(data["state"][i, 2]), data["waypoints"][i],
                                  float(data["resolution"][i]), loops)
        apes.append(a)
        hds.append(h)
    return time.perf_counter() - t0, apes, hds


class _Pixels(torch.nn.Module):
    """Baseline extractor: the image average-pooled to 8 x 8 (64 features)."""

    in_channels, feature_dim, identity = 1, 64, "pixels-8x8"

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.adaptive_avg_pool2d(x.float(), 8).flatten(1)


def fid_sensitivity(images: int, image_size: int, seed: int = 0) -> dict[str, Any]:
    """FID of ``images`` real vs as many independently drawn generated L/U paths, degraded at increasing levels
    (shift, blur, dropout, blobs: :data:`SENSITIVITY_LEVELS`), for the default shape extractor, the random conv
    extractor with three seeds and a raw-pixel baseline: does FID rise monotonically with the degradation?
    (These are drawing degradations of :mod:`spade.metrics.synthetic`'s paths; :func:`shape_validity` is about
    shape.)"""
    real = torch.from_numpy(synthetic_batch(images, size=image_size, seed=seed + 1)["path"])
    gen = synthetic_batch(images, size=image_size, seed=seed + 2)["path"]
    degraded = {(k, lv): torch.from_numpy(degrade(gen, k, lv, seed=seed + 3))
                for k, lvs in SENSITIVITY_LEVELS.items() for lv in lvs}
    rows = []
    for ext in (ShapeFeatures(), RandomConvFeatures(seed=0), RandomConvFeatures(seed=1), RandomConvFeatures(seed=2),
                _Pixels()):
        fid = FID(ext, reset_real_features=False)
        fid.update(real, real=True)
        for kind, levels in SENSITIVITY_LEVELS.items():
            values = []
            for lv in levels:
                fid.reset()
                fid.update(degraded[(kind, lv)], real=False)
                values.append(float(fid.compute()["fid"]))
            rows.append({"extractor": ext.identity, "feature_dim": ext.feature_dim, "kind": kind, "levels": levels,
                         "fid": values, "ratio": values[-1] / values[0],
                         "monotonic": all(b > a for a, b in zip(values, values[1:]))})
    return {"images": images, "image_size": image_size, "rows": rows}


SHAPE_LEVELS: dict[str, list[float]] = {"shift_px": [0, 1, 2, 4, 8], "gap": [0, 0.1, 0.2, 0.35, 0.5],
                                        "radius_scale": [1.0, 0.6, 0.3, 0.0]}
"""Growing shape corruptions of :func:`shape_validity` (shift in pixels at 64 px, missing middle fraction of the
arc length, turn radius multiplier: 0 is a sharp corner)."""


def _fid_against(extractor: Any, real: torch.Tensor, sets: dict[str, np.ndarray], batch: int = 256) -> dict[str, float]:
    """FID of every set against ``real`` with one extractor (the real statistics accumulated once)."""
    fid = FID(extractor, reset_real_features=False)
    for i in range(0, len(real), batch):
        fid.update(real[i : i + batch], real=True)
    out = {}
    for name, images in sets.items():
        fid.reset()
        t = torch.from_numpy(np.asarray(images, dtype=np.float32))
        for i in range(0, len(t), batch):
            fid.update(t[i : i + batch], real=False)
        out[name] = float(fid.compute()["fid"])
    return out


def shape_validity(images: int, image_size: int = 64, seed: int = 0,
                   extractors: tuple[str, ...] = ("shape", "randconv")) -> dict[str, Any]:
    """FID's validity on robot-frame L paths (:mod:`spade.metrics.shape_paths`, ``images`` per set): a disjoint
    ground-truth sample, straight lines, U's, sharp corners, the middle third removed, a 180 degree rotation,
    each against the ground truth, and the growing corruptions of :data:`SHAPE_LEVELS`; per extractor."""
    res = 0.1 * 64 / image_size
    scale = image_size / 64
    real = torch.from_numpy(render_paths(sample_paths(images, "L", image_size, res, seed=seed + 1), image_size))
    gen = sample_paths(images, "L", image_size, res, seed=seed + 2)
    sets = {"ground truth (disjoint sample)": render_paths(gen, image_size),
            "straight lines": render_paths(straight_paths(gen), image_size),
            "U instead of L": render_paths(sample_paths(images, "U", image_size, res, seed=seed + 2), image_size),
            "sharp corners (radius 0)": None, "middle third removed": render_paths(gen, image_size, gap=1 / 3),
            "rotated 180 degrees": render_paths(rotate_paths(gen, image_size), image_size)}
    radius = {lv: render_paths(sample_paths(images, "L", image_size, res, seed=seed + 2, radius_scale=lv), image_size)
              for lv in SHAPE_LEVELS["radius_scale"]}
    sets["sharp corners (radius 0)"] = radius[0.0]
    for lv in SHAPE_LEVELS["shift_px"][1:]:
        sets[f"shift_px={lv}"] = render_paths(gen, image_size, shift_px=lv * scale, seed=seed + 3)
    for lv in SHAPE_LEVELS["gap"][1:]:
        sets[f"gap={lv}"] = render_paths(gen, image_size, gap=lv)
    for lv in SHAPE_LEVELS["radius_scale"][1:]:
        sets[f"radius_scale={lv}"] = radius[lv]
    rows = []
    for name in extractors:
        ext = build_feature_extractor(name)
        values = _fid_against(ext, real, sets)
        base = values["ground truth (disjoint sample)"]
        fixed = [{"set": k, "fid": v, "ratio": v / base} for k, v in values.items() if "=" not in k]
        growing = []
        for kind, levels in SHAPE_LEVELS.items():
            fids = [base] + [values[f"{kind}={lv}"] for lv in levels[1:]]
            growing.append({"kind": kind, "levels": levels, "fid": fids,
                            "monotonic": all(b > a for a, b in zip(fids, fids[1:]))})
        rows.append({"extractor": ext.identity, "feature_dim": ext.feature_dim, "sets": fixed, "growing": growing})
    return {"images": images, "image_size": image_size, "rows": rows}


def _load_paths(root: str | Path, shape: str | None) -> dict[str, Any]:
    ds = PathDataset(root)
    keep = [i for i, s in enumerate(ds.labels("shape")) if shape is None or s == shape]
    items = [ds[i] for i in keep]
    if not items:
        raise ValueError(f"{root} holds no {shape!r} instances")
    return {"path": np.stack([it["path"].numpy() for it in items]),
            "state": np.stack([it["state"].numpy() for it in items]),
            "scenario": [str(it["scenario_id"]) for it in items], "resolution": float(ds.resolution)}


def fid_test_table(test_dir: str | Path, resample_dir: str | Path | None = None, shape: str | None = "L",
                   extractors: tuple[str, ...] = ("shape", "randconv")) -> dict[str, Any]:
    """The FID sensitivity table: FID against a real test set's ``shape`` ground-truth path images of the ground truth
    resampled, the classical baselines (straight line, Nav2-like shortest path, heading template; their
    polylines drawn with :func:`~spade.metrics.baselines.draw_polyline`, like the ground truth's path channel)
    and the ground truth rotated by 180 degrees, per extractor.

    ``resample_dir``: another dataset of the same distribution (e.g. the test preset with another seed); without
    one the test set is split by scenario into two halves, and every row is scored against the first half (the
    resample row is the second half).
    """
    test = _load_paths(test_dir, shape)
    n = len(test["path"])
    if resample_dir is not None:
        real_idx = np.arange(n)
        resample = _load_paths(resample_dir, shape)["path"]
        resample_note = f"{resample_dir}"
    else:
        names = sorted(set(test["scenario"]))
        first = set(names[::2])
        real_idx = np.array([i for i, s in enumerate(test["scenario"]) if s in first])
        resample = test["path"][[i for i, s in enumerate(test["scenario"]) if s not in first]]
        resample_note = "the test set's other half (by scenario)"
    real = test["path"][real_idx]
    h, w = real.shape[-2:]
    t0 = time.perf_counter()
    polys = [baseline_polylines(test["state"][i], test["resolution"]) for i in real_idx]
    drawn = {name: np.stack([draw_polyline(p[name], h, w)[None] for p in polys]) for name in BASELINES}
    baseline_s = time.perf_counter() - t0
    labels = {"straight": "straight line start -> goal", "shortest": "Nav2-like shortest path",
              "heading": "heading template"}
    sets = {"ground truth resampled": resample, **{labels[k]: v for k, v in drawn.items()},
            "ground truth rotated 180 degrees": np.rot90(real, 2, axes=(-2, -1)).copy()}
    columns = []
    fewest = min(len(real), *(len(v) for v in sets.values()))
    for name in extractors:
        ext = build_feature_extractor(name)
        t0 = time.perf_counter()
        if fewest > ext.feature_dim:
            values: dict[str, float | None] = dict(_fid_against(ext, torch.from_numpy(real), sets))
        else:  # too few images for this extractor's covariances (e.g. randconv on half a test set)
            values = dict.fromkeys(sets)
        columns.append({"extractor": ext.identity, "feature_dim": ext.feature_dim, "fid": values,
                        "seconds": time.perf_counter() - t0})
    return {"test_dir": str(test_dir), "shape": shape, "real": int(len(real)), "resample": resample_note,
            "counts": {k: int(len(v)) for k, v in sets.items()}, "baseline_seconds": baseline_s, "columns": columns}
