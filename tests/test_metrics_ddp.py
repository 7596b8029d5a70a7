"""DDP: two CPU processes (gloo) that each see part of the data compute the values of one process."""

from __future__ import annotations

import socket
from pathlib import Path

import numpy as np
import pytest
import torch
import torch.distributed as dist
import torch.multiprocessing as mp

from spade.metrics.ape import APE
from spade.metrics.fid import FID
from spade.metrics.hausdorff import HausdorffCount
from spade.metrics.synthetic import degrade, synthetic_batch

N = 260  # FID needs > 240 samples per set
SPLIT = 97  # uneven on purpose: rank 0 gets 97 instances, rank 1 the other 163


def _data() -> dict[str, torch.Tensor]:
    d = synthetic_batch(N, size=32, num_points=16, seed=7, width=2)
    pred = degrade(d["path"], "blobs", 1, seed=1) * 0.9
    pred[::9] = 0.0  # some failures / empty predictions
    out = {k: torch.from_numpy(np.asarray(v)) for k, v in d.items()}
    out["pred"] = torch.from_numpy(pred)
    return out


def _run(data: dict[str, torch.Tensor], rows: slice) -> dict[str, float]:
    ape, hd, fid = APE(), HausdorffCount(), FID()
    for start in range(rows.start, rows.stop, 50):  # several batches per process
        sl = slice(start, min(start + 50, rows.stop))
        ape.update(data["pred"][sl], data["state"][sl], data["waypoints"][sl], data["resolution"][sl])
        hd.update(data["pred"][sl], data["path"][sl])
        fid.update(data["path"][sl], real=True)
        fid.update(data["pred"][sl], real=False)
    out: dict[str, float] = {}
    for metric in (ape, hd, fid):
        out.update({k: float(v) for k, v in metric.compute().items()})
    return out


def _worker(rank: int, port: int, out_dir: str) -> None:
    torch.set_num_threads(1)
    dist.init_process_group("gloo", init_method=f"tcp://127.0.0.1:{port}", rank=rank, world_size=2)
    try:
        rows = slice(0, SPLIT) if rank == 0 else slice(SPLIT, N)
        torch.save(_run(_data(), rows), Path(out_dir) / f"rank{rank}.pt")
    finally:
        dist.destroy_process_group()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.slow  # DDP: two gloo processes; batch-split independence of each metric: test_metrics_*.py
def test_two_gloo_processes_give_the_single_process_values(tmp_path: Path) -> None:
    mp.spawn(_worker, args=(_free_port(), str(tmp_path)), nprocs=2, join=True)
    single = _run(_data(), slice(0, N))
    assert single["failures"] > 0 and single["empty"] > 0
    for rank in (0, 1):
        got = torch.load(tmp_path / f"rank{rank}.pt")
        assert got.keys() == single.keys()
        for key, value in single.items():
            # FID: float32 conv features differ in the last bits between thread counts; the sums are float64.
            rtol = 1e-6 if key == "fid" else 1e-12
            np.testing.assert_allclose(got[key], value, rtol=rtol, err_msg=f"rank {rank}: {key}")
