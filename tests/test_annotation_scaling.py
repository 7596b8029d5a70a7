"""The annotation tool splits its work below the scenario (a scenario's robot states across workers) and the output
never depends on how: worker count, start method or chunk size."""

from __future__ import annotations

import json
import math
import multiprocessing
import platform
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest
from omegaconf import OmegaConf

from spade.annotate import annotate
from spade.annotation import pipeline
from spade.annotation.pipeline import RunStats, build_contexts, ordered_results, scenario_tasks, template_instances
from spade.annotation.scenarios import generate_scenario
from spade.annotation.sources import load_map_sources

ROOT = Path(__file__).resolve().parents[1]
RUN_SETTINGS = ("workers", "states_per_task", "start_method", "out_dir")  # how a run was computed, not what


def tiny_cfg(out_dir: Path, **over) -> dict:
    """One procedural map, both shapes, 64 px x 0.1 m/px windows: two or three scenarios of 20-30 states."""
    cfg = OmegaConf.to_container(OmegaConf.load(ROOT / "conf" / "annotate.yaml"), resolve=False)
    cfg.pop("defaults", None)
    cfg.pop("hydra", None)
    cfg.update(out_dir=str(out_dir), workers=1, progress=False, num_instances=40, num_waypoints=16,
               maps=["warehouse:1"], shape=["L", "U"], seed=7)
    cfg["window"].update(size_px=64, resolution_m=0.1)
    cfg["instances"]["spacing_m"] = 0.15
    cfg["preview"]["enabled"] = False
    cfg.update(over)
    return cfg


def arrays(root: Path) -> dict[str, np.ndarray]:
    manifest = json.loads((root / "manifest.json").read_text())
    out = {}
    for name, info in manifest["files"].items():
        flat = np.fromfile(root / info["file"], dtype=np.dtype(info["dtype"]))
        out[name] = flat.reshape(manifest["num_instances"], *info["row_shape"])
    return out


def manifest_without_run_settings(root: Path) -> dict:
    manifest = json.loads((root / "manifest.json").read_text())
    manifest.pop("manifest_sha256")
    for key in RUN_SETTINGS:
        manifest["generator"].pop(key)
    return manifest


@pytest.mark.skipif("fork" not in multiprocessing.get_all_start_methods(), reason="needs the fork start method")
def test_worker_count_and_chunking_never_change_the_dataset(tmp_path: Path) -> None:
    """workers=1 against workers=2 with a scenario's states in tasks of 2 (fork here, for seconds; the default
    spawn: test_annotation_pipeline.py::test_worker_count_never_changes_the_bytes): same arrays, same manifest
    (file checksums, labels, scenarios, rejections, skipped states) but for the run settings."""
    annotate(tiny_cfg(tmp_path / "w1"))
    annotate(tiny_cfg(tmp_path / "w2", workers=2, states_per_task=2, start_method="fork"))
    annotate(tiny_cfg(tmp_path / "w1_chunks", states_per_task=1))
    reference = arrays(tmp_path / "w1")
    assert len(reference["occupancy"]) == 40
    scenarios = json.loads((tmp_path / "w1" / "manifest.json").read_text())["extra"]["scenarios"]
    assert 2 <= len(scenarios) <= 4 and sum(s["instances"] for s in scenarios) == 40
    for other in ("w2", "w1_chunks"):
        got = arrays(tmp_path / other)
        assert set(got) == set(reference)
        for name in reference:
            assert np.array_equal(got[name], reference[name]), (other, name)
        assert manifest_without_run_settings(tmp_path / other) == manifest_without_run_settings(tmp_path / "w1")


class _SlowThreads(ThreadPoolExecutor):
    """Threads as workers (they share this process's contexts); every task lasts at least 20 ms, and what runs
    at once is recorded per task kind and scenario."""

    def __init__(self, workers: int) -> None:
        super().__init__(max_workers=workers)
        self.lock = threading.Lock()
        self.running: dict[tuple[str, int], int] = {}
        self.most: dict[tuple[str, int], int] = {}
        self.submitted: list[tuple[str, int]] = []

    def submit(self, fn, /, *args, **kwargs):  # type: ignore[override]
        key = (fn.__name__, id(args[1]) if fn.__name__ == "_states_task" else -1)
        self.submitted.append(key)

        def run():
            with self.lock:
                self.running[key] = self.running.get(key, 0) + 1
                self.most[key] = max(self.most.get(key, 0), self.running[key])
            try:
                time.sleep(0.02)
                return fn(*args, **kwargs)
            finally:
                with self.lock:
                    self.running[key] -= 1

        return super().submit(run)


def _contexts(cfg: dict) -> list:
    return build_contexts(load_map_sources(cfg["maps"], float(cfg["window"]["resolution_m"])), cfg)


def test_one_scenario_is_shared_by_the_workers(tmp_path: Path) -> None:
    """One scenario's states go out in ceil(pending / states_per_task) tasks that run at once on the workers, and
    the scenarios come back as :func:`generate_scenario` computes them in one piece."""
    cfg = tiny_cfg(tmp_path / "unused", shape=["U"])
    contexts = _contexts(cfg)
    pipeline.init_worker(contexts, cfg)
    tasks = list(scenario_tasks(1, ["U"], 2))
    with _SlowThreads(2) as executor:
        got = [r for _, r in ordered_results(executor, iter(tasks), workers=2, states_per_task=3)]
    for (m, shape, k), result in zip(tasks, got, strict=True):
        whole = generate_scenario(contexts[m], shape, k, cfg)
        assert result.scenario_id == whole.scenario_id and result.skipped == whole.skipped
        assert result.rejections == whole.rejections and len(result.instances) == len(whole.instances) > 10
        assert len(result.pending) == 0
        for a, b in zip(result.instances, whole.instances, strict=True):
            assert np.array_equal(a.occupancy, b.occupancy) and np.array_equal(a.path, b.path)
            assert np.array_equal(a.waypoints, b.waypoints) and a.pose == b.pose
    chunk_keys = [key for key in executor.submitted if key[0] == "_states_task"]
    per_path = {}
    for key in chunk_keys:
        per_path[key] = per_path.get(key, 0) + 1
    assert sorted(per_path.values()) == sorted(math.ceil((len(r.instances) - 1) / 3) for r in got)
    assert max(executor.most[key] for key in per_path) == 2  # both workers on one scenario's states at once


def test_no_more_scenarios_are_planned_than_the_run_needs(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Fewer instances than one scenario gives: at most one plan per worker, never the 3 x workers look-ahead."""
    cfg = tiny_cfg(tmp_path / "unused", shape=["L"], num_instances=5, workers=4)
    contexts = _contexts(cfg)
    executor = _SlowThreads(4)

    def threads(workers, start_method, ctxs, c):
        pipeline.init_worker(ctxs, c)
        return executor

    monkeypatch.setattr(pipeline, "_executor", threads)
    stats = RunStats()
    items = list(template_instances(contexts, cfg, stats))
    executor.shutdown(wait=True)
    assert len(items) == 5 and len(stats.scenarios) == 1
    assert 1 <= executor.submitted.count(("_plan_task", -1)) <= 4


def test_states_per_task_below_one_is_refused(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="states_per_task must be >= 1"):
        annotate(tiny_cfg(tmp_path / "ds", states_per_task=0))
    assert not (tmp_path / "ds").exists()


def _keep_freed_blocks_in_child(_: int) -> bool:
    return pipeline.keep_freed_blocks()


@pytest.mark.skipif(platform.libc_ver()[0] != "glibc" or "fork" not in multiprocessing.get_all_start_methods(),
                    reason="glibc's mallopt, in a forked child")
def test_workers_keep_freed_blocks_on_glibc() -> None:
    """A pool worker sets glibc's mmap and trim thresholds (a fresh process otherwise page-faults on every window's
    temporaries); checked in a child so that this process's allocator is left as it is."""
    with multiprocessing.get_context("fork").Pool(1) as pool:
        assert pool.map(_keep_freed_blocks_in_child, [0]) == [True]
