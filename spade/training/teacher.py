"""The expert as a planner, beside the student it is meant to teach (``spade.critic``'s planner figures).

A teacher is worth its cost only where it plans better than its student. For each test instance the expert draws
``samples`` (K) independent DDIM samples; the planner (:class:`~spade.metrics.decoding.PathDecoder`) decodes

- the first sample: ``expert/planner/*`` (what a robot asking the expert once would drive: APE, tail, failures,
  floor ratio, plausibility, commitment);
- the mean of the K probability maps: ``expert/mean_map/planner/*`` (what K samples buy, blended);
- the medoid of the K samples' decoded paths: ``expert/medoid/planner/*`` (what K samples buy, committed: the
  minimum-Bayes-risk reading, :func:`~spade.metrics.preference.medoid_path`);
- the first two: ``expert/spread_cm`` against ``expert/generator_spread_cm`` (the operator's own spread, from the
  test set's alternatives) and their ratio (:class:`~spade.metrics.preference.SpreadMetrics`);

and, given a student, the student's prediction on the same instances: ``student/planner/*``.
``expert/seconds_per_sample`` is the sampling time per instance and sample on this machine. The expert's own test
(:meth:`ExpertModule.test_step`) logs the same figures under ``test/``.
"""

from __future__ import annotations

import time
from collections.abc import Iterable
from typing import Any

import torch
from spade.metrics.baselines import draw_polylines
from spade.metrics.path_metrics import PathMetrics
from spade.metrics.preference import medoid_path, SpreadMetrics

__all__ = ["planner_figures", "sample_maps", "two_sample_paths"]


@torch.no_grad()
def sample_maps(expert: Any, state: torch.Tensor, samples: int) -> tuple[list[torch.Tensor], float]:
    """``samples`` independent path maps of ``expert`` for ``state`` (seeds ``sample_seed``, ``+1``, ...) and the
    seconds they took: the K samples of the expert as a planner, in its test and in ``spade.critic``."""
    seed = int(expert.hparams.get("sample_seed", 0))
    t0 = time.perf_counter()
    maps = [expert.sample_paths(state, seed=seed + i) for i in range(samples)]
    return maps, time.perf_counter() - t0


def medoid_reading(metrics: Any, decode: Any, maps: list[torch.Tensor], batch: dict,
                   decoded: list[list[Any]] | None = None) -> None:
    """Update ``metrics`` (a :class:`~spade.metrics.path_metrics.PathMetrics`) with the minimum-Bayes-risk reading of
    the K sample ``maps``: each instance's medoid of its samples' decoded paths
    (:func:`~spade.metrics.preference.medoid_path`). ``decoded``: the paths of the first maps already decoded."""
    decoded = list(decoded or [])
    for m in maps[len(decoded):]:
        decoded.append([d.points if d.ok else None for d in decode(m, batch["state"], batch["resolution"])])
    medoids = [medoid_path([paths[i] for paths in decoded]) for i in range(len(decoded[0]))]
    h, w = maps[0].shape[-2:]
    metrics.update(draw_polylines(medoids, h, w, maps[0].device), batch, polylines=medoids)


def two_sample_paths(decode: Any, maps: list[torch.Tensor], batch: dict) -> list[list[Any]]:
    """The planner's paths (None where it failed) of the first two sample maps: what the spread compares."""
    return [[d.points if d.ok else None for d in decode(m, batch["state"], batch["resolution"])] for m in maps[:2]]


@torch.no_grad()
def planner_figures(expert: Any, loader: Iterable[dict], samples: int = 4, student: torch.nn.Module | None = None,
                    max_instances: int | None = None) -> dict[str, float]:
    """The figures of the module docstring for ``expert`` (an :class:`ExpertModule`) on ``loader``'s instances
    (at most ``max_instances``)."""
    if isinstance(samples, bool) or not isinstance(samples, int) or samples < 2:
        raise ValueError(f"samples must be an integer >= 2 (two samples measure the spread), got {samples!r}")
    options = {**dict(expert.hparams.get("metrics") or {}), "fid": False}
    single, mean_map, medoid = PathMetrics(**options), PathMetrics(**options), PathMetrics(**options)
    taught = PathMetrics(**options) if student is not None else None
    spread = SpreadMetrics()
    seconds, count, seen = 0.0, 0, 0
    for batch in loader:
        if max_instances is not None and seen >= max_instances:
            break
        take = slice(None) if max_instances is None else slice(0, max_instances - seen)
        batch = {k: (v[take] if isinstance(v, torch.Tensor) and v.dim() > 0 else v) for k, v in batch.items()}
        state = batch["state"].float()
        maps, took = sample_maps(expert, state, samples)
        seconds += took
        count += state.shape[0] * samples
        single.update(maps[0], batch)
        mean_map.update(torch.stack(maps).mean(0), batch)
        paths = two_sample_paths(single.decode, maps, {**batch, "state": state})
        medoid_reading(medoid, single.decode, maps, {**batch, "state": state}, paths)
        spread.update(paths[0], paths[1], batch["waypoints"], batch.get("alternatives"), batch["resolution"])
        if taught is not None:
            taught.update(torch.sigmoid(student(state)), batch)
        seen += state.shape[0]
    if not seen:
        raise ValueError("the expert planned no test instance: check data.test_dir (an empty or missing test set)")

    def planner(metrics: PathMetrics, prefix: str) -> dict[str, float]:
        return {f"{prefix}/{k}": float(v) for k, v in metrics.compute().items() if k.startswith("planner/")}

    out = {**planner(single, "expert"), **planner(mean_map, "expert/mean_map"), **planner(medoid, "expert/medoid")}
    s = spread.compute()
    out.update({"expert/spread_cm": float(s["spread_cm"]), "expert/generator_spread_cm": float(s["generator_spread_cm"]),
                "expert/spread_ratio": float(s["spread_ratio"]), "expert/seconds_per_sample": seconds / count,
                "expert/samples": float(samples), "expert/instances": float(seen)})
    if taught is not None:
        out.update(planner(taught, "student"))
    return out
