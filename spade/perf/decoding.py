"""Cost of the planner's search decoder against the paper's extraction, per instance on one core."""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from spade.metrics.decoding import PathDecoder
from spade.metrics.extraction import extract_path, marker_centre
from spade.metrics.synthetic import synthetic_batch, synthetic_predictions


def decoder_costs(instances: int, image_sizes: list[int], seed: int = 0) -> list[dict[str, Any]]:
    """Median and 95th-percentile wall time (ms) per instance of :class:`PathDecoder` (search) and of
    :func:`extract_path` (skeleton) on ``instances`` synthetic soft L/U predictions at each image size (CPU time
    is reported too: on a loaded machine it is the steadier figure)."""
    rows = []
    for size in image_sizes:
        batch = synthetic_batch(instances, size=size, seed=seed, resolution=6.4 / size)
        prob = synthetic_predictions(batch["path"], seed=seed)[:, 0]
        state = batch["state"]
        k = batch["waypoints"].shape[1]
        decoder = PathDecoder(num_points=k, force_endpoints=True)
        timings: dict[str, list[float]] = {"search": [], "skeleton": []}
        cpu: dict[str, float] = {"search": 0.0, "skeleton": 0.0}
        for i in range(instances):
            start, goal = marker_centre(state[i, 1]), marker_centre(state[i, 2])
            grid = np.rint(state[i, 0] * 2).astype(np.uint8)
            for name, run in (("search", lambda: decoder(prob[i], grid, start, goal, 6.4 / size)),
                              ("skeleton", lambda: extract_path(prob[i], start, goal, k))):
                t0, c0 = time.perf_counter(), time.process_time()
                run()
                timings[name].append(1e3 * (time.perf_counter() - t0))
                cpu[name] += 1e3 * (time.process_time() - c0)
        for name, ms in timings.items():
            rows.append({"decoder": name, "image_size": size, "instances": instances,
                         "median_ms": round(float(np.median(ms)), 3), "p95_ms": round(float(np.percentile(ms, 95)), 3),
                         "cpu_ms_per_instance": round(cpu[name] / instances, 3)})
    return rows
