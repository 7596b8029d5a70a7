"""Benchmark of SPADE's metrics (prints measured figures; not a timed test).

1. APE + Hd19 over N predicted 128 x 128 paths (torchmetrics update + compute), next to a straightforward
   per-instance reference pipeline of the kind SKIPP uses (thin, dense pixel adjacency matrix, all-pairs
   shortest paths, resample, evo's APE; scipy's directed_hausdorff both ways), timed in the same run on the
   same predictions, with the ratio and the agreement of the values.
2. FID update + compute for N real and N generated images with the default extractor.
3. With --sensitivity: FID of degraded path sets (shift, blur, dropout, stray blobs) for the default random
   conv extractor, two other seeds and a raw-pixel baseline: is FID monotonic in the degradation?

Run: python benchmarks/bench_metrics.py [--n 2000] [--reference-n 2000] [--sensitivity]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from scipy import ndimage
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import shortest_path
from scipy.spatial.distance import directed_hausdorff
from skimage.morphology import thin

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from spade.data.polyline import resample_polyline  # noqa: E402
from spade.metrics import APE, FID, HausdorffCount, RandomConvFeatures, marker_centre  # noqa: E402
from spade.metrics.testing import degrade, synthetic_batch  # noqa: E402


def make_predictions(n: int, size: int, seed: int) -> dict[str, np.ndarray]:
    """Synthetic ground truth plus plausible soft predictions: blurred, slightly shifted, some with artifacts."""
    data = synthetic_batch(n, size=size, num_points=64, seed=seed, width=2, resolution=0.05)
    rng = np.random.default_rng(seed + 1)
    pred = np.empty_like(data["path"])
    for i in range(n):
        img = ndimage.gaussian_filter(data["path"][i, 0], 0.8)
        img = ndimage.shift(img, rng.normal(0, 0.7, 2), order=1)
        img = np.clip(img / max(img.max(), 1e-6) * 0.95 + rng.normal(0, 0.03, img.shape), 0, 1)
        pred[i, 0] = img
    blobs = rng.random(n) < 0.10
    pred[blobs] = np.maximum(pred[blobs], degrade(np.zeros_like(pred[blobs]), "blobs", 1, seed=seed + 2))
    gaps = rng.random(n) < 0.05
    pred[gaps] = degrade(pred[gaps], "dropout", 0.1, seed=seed + 3)
    pred[rng.random(n) < 0.02] = 0.0
    data["pred"] = pred.astype(np.float32)
    return data


def ours(data: dict[str, np.ndarray], batch: int = 64) -> tuple[float, dict, dict, APE, HausdorffCount]:
    t = {k: torch.from_numpy(np.asarray(v)) for k, v in data.items()}
    ape, hd = APE(), HausdorffCount()
    start = time.perf_counter()
    for i in range(0, len(t["pred"]), batch):
        sl = slice(i, i + batch)
        ape.update(t["pred"][sl], t["state"][sl], t["waypoints"][sl], t["resolution"][sl])
        hd.update(t["pred"][sl], t["path"][sl])
    a, h = ape.compute(), hd.compute()
    return time.perf_counter() - start, a, h, ape, hd


def reference_instance(pred: np.ndarray, truth_mask: np.ndarray, start: np.ndarray, goal: np.ndarray,
                       waypoints: np.ndarray, resolution: float, loops: bool = False) -> tuple[float | None, float]:
    """One instance the straightforward way: dense adjacency, all-pairs shortest paths, evo; scipy Hausdorff.

    ``loops``: fill the adjacency matrix with a Python double loop over pixel pairs, literally as SKIPP's
    ``find_longest_path`` does (otherwise numpy broadcasting, which is kinder to the reference).
    """
    from evo.core import metrics as evo_metrics
    from evo.core.trajectory import PosePath3D

    mask = pred >= 0.5
    hd = float("inf")
    if mask.any():
        a, b = np.argwhere(mask).astype(float), np.argwhere(truth_mask > 0.5).astype(float)
        hd = max(directed_hausdorff(a, b)[0], directed_hausdorff(b, a)[0])
    skel = thin(mask)
    pts = np.argwhere(skel)[:, ::-1].astype(float)  # (x, y)
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
    apes, hds = [], []
    start = time.perf_counter()
    for i in range(n):
        s = marker_centre(data["state"][i, 1])
        g = marker_centre(data["state"][i, 2])
        a, h = reference_instance(data["pred"][i, 0], data["path"][i, 0], s, g, data["waypoints"][i],
                                  float(data["resolution"][i]), loops)
        apes.append(a)
        hds.append(h)
    return time.perf_counter() - start, apes, hds


def bench_fid(n: int, size: int) -> None:
    real = torch.from_numpy(synthetic_batch(n, size=size, seed=11, width=2)["path"])
    fake = torch.from_numpy(degrade(synthetic_batch(n, size=size, seed=12, width=2)["path"], "blur", 0.7))
    fid = FID()
    t0 = time.perf_counter()
    for i in range(0, n, 100):
        fid.update(real[i : i + 100], real=True)
        fid.update(fake[i : i + 100], real=False)
    t1 = time.perf_counter()
    value = fid.compute()["fid"].item()
    t2 = time.perf_counter()
    print(f"FID ({fid.identity}, D={fid.feature_dim}) over {n} real + {n} generated {size}x{size} images:")
    print(f"  update {t1 - t0:.2f} s ({(t1 - t0) / (2 * n) * 1e3:.2f} ms/image), compute {t2 - t1:.3f} s, FID = {value:.4f}")


class _Pixels(torch.nn.Module):
    """Baseline: the image average-pooled to 8 x 8 (64 features)."""

    in_channels, feature_dim, identity = 1, 64, "pixels-8x8"

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.adaptive_avg_pool2d(x.float(), 8).flatten(1)


def sensitivity(n: int, size: int) -> None:
    levels = {"shift": [0, 1, 2, 4, 8], "blur": [0, 0.5, 1, 2, 3], "dropout": [0, 0.1, 0.2, 0.4, 0.6],
              "blobs": [0, 1, 2, 4, 8]}
    real = torch.from_numpy(synthetic_batch(n, size=size, seed=1)["path"])
    gen = synthetic_batch(n, size=size, seed=2)["path"]
    degraded = {(k, lv): torch.from_numpy(degrade(gen, k, lv, seed=3)) for k, lvs in levels.items() for lv in lvs}
    extractors = [RandomConvFeatures(seed=0), RandomConvFeatures(seed=1), RandomConvFeatures(seed=2), _Pixels()]
    print(f"FID sensitivity: {n} real vs {n} generated {size}x{size} L/U paths (independent draws), degraded:")
    for ext in extractors:
        fid = FID(ext)
        fid.update(real, real=True)
        saved = {k: getattr(fid, k).clone() for k in ("real_n", "real_sum", "real_outer")}
        print(f"  {ext.identity} (D={ext.feature_dim})")
        for kind, lvs in levels.items():
            vals = []
            for lv in lvs:
                fid.reset()
                for k, v in saved.items():
                    setattr(fid, k, v.clone())
                fid.update(degraded[(kind, lv)], real=False)
                vals.append(fid.compute()["fid"].item())
            mono = all(b > a for a, b in zip(vals, vals[1:]))
            ratio = vals[-1] / vals[0]
            print(f"    {kind:8s} levels {lvs}: " + " ".join(f"{v:.4g}" for v in vals)
                  + f"  (x{ratio:.1f}; {'monotonic' if mono else 'NOT monotonic'})")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--n", type=int, default=2000, help="instances / images (default 2000)")
    parser.add_argument("--size", type=int, default=128)
    parser.add_argument("--reference-n", type=int, default=2000, help="instances through the reference pipeline")
    parser.add_argument("--loops-n", type=int, default=50,
                        help="instances through the reference with SKIPP's literal Python adjacency loops")
    parser.add_argument("--sensitivity", action="store_true", help="also run the FID sensitivity study")
    args = parser.parse_args()
    torch.manual_seed(0)
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads")

    data = make_predictions(args.n, args.size, seed=0)
    secs, a, h, ape, hd = ours(data)
    print(f"APE + Hd19 (spade.metrics) over {args.n} predicted {args.size}x{args.size} paths: {secs:.2f} s "
          f"({secs / args.n * 1e3:.2f} ms/instance)")
    print("  " + ", ".join(f"{k}={float(v):.4g}" for k, v in {**a, **h}.items()))

    m = min(args.reference_n, args.n)
    if m > 0:
        rsecs, rapes, rhds = reference(data, m)
        per_ref, per_ours = rsecs / m, secs / args.n
        print(f"Reference pipeline (thin + dense adjacency + all-pairs shortest paths + evo; directed_hausdorff) "
              f"over {m} instances: {rsecs:.2f} s ({per_ref * 1e3:.2f} ms/instance"
              + (f", {per_ref * args.n:.1f} s extrapolated to {args.n}" if m < args.n else "") + ")")
        print(f"  speed-up of spade.metrics: x{per_ref / per_ours:.1f} per instance")
        ours_hd = hd.per_instance().numpy()[:m]
        ref_hd = np.array(rhds)
        same = np.isinf(ours_hd) == np.isinf(ref_hd)
        fin = np.isfinite(ours_hd) & np.isfinite(ref_hd)
        print(f"  Hausdorff agreement: max |diff| {np.abs(ours_hd[fin] - ref_hd[fin]).max():.2e} px, "
              f"empty flags equal: {bool(same.all())}")
        sub = {k: v[:m] for k, v in data.items()}
        _, a_sub, _, ape_sub, _ = ours(sub)
        ok = np.array([v is not None for v in rapes])
        print(f"  same {m} instances: reference APE mean {np.mean(np.array(rapes, dtype=float)[ok]):.3f} cm "
              f"(failures {m - ok.sum()}), median {np.median(np.array(rapes, dtype=float)[ok]):.3f} cm; "
              f"spade.metrics APE mean {float(a_sub['ape_cm']):.3f} cm (failures {int(a_sub['failures'])}), "
              f"median {float(a_sub['ape_median_cm']):.3f} cm")

    if args.loops_n > 0:
        lsecs, _, _ = reference(data, min(args.loops_n, args.n), loops=True)
        per_loop = lsecs / min(args.loops_n, args.n)
        print(f"Reference with SKIPP's literal Python adjacency loops over {min(args.loops_n, args.n)} instances: "
              f"{per_loop * 1e3:.1f} ms/instance ({per_loop * args.n:.0f} s extrapolated to {args.n}; "
              f"x{per_loop / (secs / args.n):.0f} slower than spade.metrics)")

    bench_fid(args.n, args.size)
    if args.sensitivity:
        sensitivity(600, 64)


if __name__ == "__main__":
    main()
