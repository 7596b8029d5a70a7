"""The annotation run: maps -> scenarios (in a process pool) -> instances written in scenario order.

Scenarios are enumerated round-robin (for k = 0, 1, ...: for every map: for every shape) and consumed strictly
in that order, however many workers compute them, until ``num_instances`` are collected; every scenario
draws from its own seeded generator, so the output bytes never depend on the worker count.

The work is split below the scenario: a worker plans a scenario (its accepted executed path and first instance),
then the path's other robot states go to the workers in tasks of ``states_per_task`` states, so a set with few
long scenarios (one real map, a few hundred instances) keeps every worker busy. A state's instance depends only on
the map, the path and the state's index, so the chunking never changes the output either.
"""

from __future__ import annotations

import itertools
import logging
import multiprocessing
import os
from collections import Counter, deque
from concurrent.futures import FIRST_COMPLETED, Executor, Future, ProcessPoolExecutor, wait
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator, Mapping

import numpy as np

from spade.annotation.alternative_demonstrations import ALTERNATIVES_VERSION, ESTIMATOR, AlternativesSettings
from spade.annotation.execution import ExecutedPath, Rejection, execute_sketch
from spade.annotation.scenarios import (
    MapContext,
    ScenarioResult,
    attach_alternatives,
    instances_along,
    plan_alternatives,
    plan_scenario,
    prepare_map,
    rasterise_states,
    window_frame,
)
from spade.annotation.split import Split, in_scenario_part, parse_split
from spade.annotation.templates import SHAPES, check_shape
from spade.data.rasterize import Instance
from spade.utils.errors import UserError
from spade.annotation.sketch_file import densify
from spade.data import DatasetWriter
from spade.maps.frame import RobotFrame
from spade.utils.processes import pid_alive, process_start

log = logging.getLogger(__name__)


class NotEnoughInstancesError(UserError, RuntimeError):
    """The maps cannot give as many instances as were asked for."""


@dataclass
class RunStats:
    """What the manifest records about a run besides the instances."""

    rejections: Counter = field(default_factory=Counter)
    rejections_by_map: dict[str, Counter] = field(default_factory=dict)
    skipped_states: Counter = field(default_factory=Counter)
    scenarios: list[dict[str, Any]] = field(default_factory=list)
    scenarios_tried: int = 0
    alternatives: Counter = field(default_factory=Counter)  # the alternatives sampler's counters, summed

    def add(self, result: ScenarioResult) -> None:
        self.scenarios_tried += 1
        self.alternatives.update(result.alternative_stats)
        self.rejections.update(result.rejections)
        self.skipped_states.update(result.skipped)
        self.rejections_by_map.setdefault(result.map_id, Counter()).update(result.rejections)

    def to_json(self) -> dict[str, Any]:
        attempts = sum(v for k, v in self.rejections.items() if k != "scenario_failed") + len(self.scenarios)
        return {
            "rejections": dict(sorted(self.rejections.items())),
            "rejections_by_map": {k: dict(sorted(v.items())) for k, v in sorted(self.rejections_by_map.items())},
            "skipped_states": dict(sorted(self.skipped_states.items())),
            "attempts": attempts,
            "scenarios_tried": self.scenarios_tried,
            "scenarios_accepted": len(self.scenarios),
            "scenarios": self.scenarios,
            **({"alternatives_sampler": dict(sorted(self.alternatives.items()))} if self.alternatives else {}),
        }


def states_per_task(cfg: Mapping[str, Any]) -> int:
    """``states_per_task``: robot states rasterised per worker task (8 when the config has no such key)."""
    value = cfg.get("states_per_task")
    value = 8 if value is None else int(value)
    if value < 1:
        raise ValueError(f"states_per_task must be >= 1, got {value}")
    return value


def alternatives_count(cfg: Mapping[str, Any]) -> int:
    """``alternatives.count``: alternative demonstrations drawn per instance (0 when the config has none)."""
    return AlternativesSettings.from_cfg(cfg.get("alternatives")).count


def shapes_of(cfg: Mapping[str, Any]) -> list[str]:
    """``shape`` as a list of checked labels (``L``, ``U`` or both)."""
    value = cfg["shape"]
    shapes = [value] if isinstance(value, str) else list(value)
    if not shapes:
        raise ValueError("shape= is empty; use shape=L, shape=U or shape=[L,U]")
    return [check_shape(str(s)) for s in shapes]


# ----------------------------------------------------------------------------------------- worker side
_WORKER: dict[str, Any] = {}


def init_worker(contexts: list[MapContext], cfg: Mapping[str, Any], parent: int | None = None) -> None:
    _WORKER["contexts"] = contexts
    _WORKER["cfg"] = cfg
    if parent is not None:
        keep_freed_blocks()
        exit_with_parent(parent)


_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3  # glibc's mallopt parameters (malloc.h)


def keep_freed_blocks(mmap_threshold: int = 32 << 20, trim_threshold: int = 64 << 20) -> bool:
    """Let glibc's malloc keep the blocks a window's rasterisation frees (a fresh worker process hands every
    block over 128 KiB back to the kernel at once until its threshold adapts, and takes page faults on the next
    window's temporaries: about 1,000 per 128 px instance, 40 % more CPU than the same work in a process that has
    run for a while). False where the C library has no ``mallopt`` (not glibc); nothing else changes."""
    import ctypes
    import ctypes.util

    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    return bool(mallopt(_M_MMAP_THRESHOLD, mmap_threshold)) and bool(mallopt(_M_TRIM_THRESHOLD, trim_threshold))


def exit_with_parent(parent: int, interval_s: float = 0.5) -> None:
    """End this (worker) process as soon as ``parent`` is gone, e.g. after a ``kill -9`` or SIGTERM of the
    annotation run: a watchdog thread polls the parent (a pool worker would otherwise keep running, orphaned,
    and keep multiprocessing's resource tracker alive). Linux's parent-death signal is not used: it fires when
    the parent *thread* that started the worker ends, which a pool does not promise to outlive."""
    import threading
    import time

    start = process_start(parent)  # a reused pid is not taken for the parent (start method fork, spawn or forkserver)
    if start is None and not pid_alive(parent):  # gone already
        os._exit(1)

    ppid = os.getppid()  # the parent itself (fork, spawn) or the forkserver: reparented when it dies

    def watch() -> None:
        while os.getppid() == ppid and pid_alive(parent, start):
            time.sleep(interval_s)
        os._exit(1)

    threading.Thread(target=watch, name="spade-parent-watchdog", daemon=True).start()


def _plan_task(map_index: int, shape: str, index: int) -> ScenarioResult:
    return plan_scenario(_WORKER["contexts"][map_index], shape, index, _WORKER["cfg"])


def _alternatives_task(map_index: int, result: ScenarioResult) -> tuple[dict[int, np.ndarray], dict[str, int]]:
    return plan_alternatives(_WORKER["contexts"][map_index], result, _WORKER["cfg"])


def _states_task(map_index: int, points: np.ndarray, indices: np.ndarray) -> tuple[list[Instance], Counter]:
    skipped: Counter = Counter()
    instances, _ = rasterise_states(_WORKER["contexts"][map_index], points, indices, _WORKER["cfg"], skipped)
    return instances, skipped


class _InlineExecutor(Executor):
    """Runs tasks at submit time, in this process (workers <= 1)."""

    def submit(self, fn: Callable[..., Any], /, *args: Any, **kwargs: Any) -> Future:
        fut: Future = Future()
        try:
            fut.set_result(fn(*args, **kwargs))
        except BaseException as exc:  # surfaced by .result(), like a pool would
            fut.set_exception(exc)
        return fut


def _executor(workers: int, start_method: str, contexts: list[MapContext], cfg: Mapping[str, Any]) -> Executor:
    if workers <= 1:
        init_worker(contexts, cfg)
        return _InlineExecutor()
    return ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context(start_method),
                               initializer=init_worker, initargs=(contexts, cfg, os.getpid()))


@dataclass
class _Slot:
    """One scenario on its way through the pool: its plan, then its chunks of states."""

    map_index: int
    shape: str
    plan: Future
    result: ScenarioResult | None = None
    todo: deque = field(default_factory=deque)  # chunks of state indices not submitted yet
    chunks: list[Future] = field(default_factory=list)
    wants_alternatives: bool = False  # its alternatives task is still to submit
    alternatives: Future | None = None


def state_chunks(pending: np.ndarray, size: int) -> list[np.ndarray]:
    """``pending`` state indices in consecutive chunks of at most ``size`` (one worker task each)."""
    size = max(1, int(size))
    return [pending[i:i + size] for i in range(0, len(pending), size)]


def ordered_results(executor: Executor, tasks: Iterable[tuple[int, str, int]], workers: int, states_per_task: int,
                    lookahead: int | None = None, needed: Callable[[int, str], bool] = lambda m, s: True,
                    remaining: Callable[[], float] = lambda: float("inf"), alternatives: bool = False
                    ) -> Iterator[tuple[int, ScenarioResult]]:
    """(map index, complete result) of the scenario ``tasks`` in task order, however the work was split.

    Each scenario is one plan task (:func:`plan_scenario`: its accepted path and first instance), then its
    remaining robot states in tasks of ``states_per_task`` (:func:`rasterise_states`), so that the workers share
    the states of one scenario instead of waiting on a few long ones. At most ``2 * workers`` tasks are in
    flight (one in this process); chunks of earlier scenarios go before the plans of later ones. Scenarios are
    planned ahead of the consumer while they are likely to be needed: at most ``lookahead`` of them (default
    ``3 * workers``, one in this process), and no more once the planned ones promise the ``remaining()``
    instances the consumer still wants (plans in flight count as the mean scenario so far; before any is known,
    at most ``workers`` plans are in flight). ``needed(map index, shape)`` false: the scenario's states are not
    rasterised (the consumer will skip it). Submitting stops when the consumer stops iterating; a task's error
    is raised when its scenario is reached, as if computed in order. What is computed ahead never changes what
    is yielded. With ``alternatives``, each needed scenario also gets one task that draws its states' alternative
    demonstrations (:func:`~spade.annotation.scenarios.plan_alternatives`), submitted before its chunks.
    """
    capacity = 1 if workers <= 1 else 2 * workers
    lookahead = max(1, (1 if workers <= 1 else 3 * workers) if lookahead is None else lookahead)
    slots: deque[_Slot] = deque()
    plans: dict[Future, _Slot] = {}
    in_flight: set[Future] = set()
    it = iter(tasks)
    exhausted = False
    known = [0, 0]  # scenarios planned so far, and the instances they promise

    def promised(slot: _Slot) -> int:
        r = slot.result
        return 0 if r is None or r.executed is None else len(r.instances) + len(r.pending)

    def planned(slot: _Slot) -> None:
        if slot.plan.exception() is not None:
            return  # raised when the slot is consumed
        slot.result = slot.plan.result()
        known[0] += 1
        known[1] += promised(slot)
        if slot.result.executed is not None and needed(slot.map_index, slot.shape):
            slot.todo.extend(state_chunks(slot.result.pending, states_per_task))
            slot.wants_alternatives = alternatives

    def worth_planning() -> bool:
        if len(slots) >= lookahead:
            return False
        if not known[0]:
            return len(plans) < max(1, workers)
        expected = sum(promised(s) for s in slots) + len(plans) * known[1] / known[0]
        return expected < remaining()

    def fill() -> None:
        nonlocal exhausted
        while len(in_flight) < capacity:
            slot = next((s for s in slots if s.wants_alternatives or s.todo), None)
            if slot is not None and slot.wants_alternatives:
                slot.wants_alternatives = False
                slot.alternatives = executor.submit(_alternatives_task, slot.map_index, slot.result)
                in_flight.add(slot.alternatives)
                continue
            if slot is not None:
                assert slot.result is not None and slot.result.executed is not None
                fut = executor.submit(_states_task, slot.map_index, slot.result.executed.points, slot.todo.popleft())
                slot.chunks.append(fut)
                in_flight.add(fut)
                continue
            if exhausted or not worth_planning():
                return
            task = next(it, None)
            if task is None:
                exhausted = True
                return
            fut = executor.submit(_plan_task, *task)
            slot = _Slot(task[0], task[1], fut)
            slots.append(slot)
            plans[fut] = slot
            in_flight.add(fut)

    def collect() -> None:
        for fut in [f for f in in_flight if f.done()]:
            in_flight.discard(fut)
            slot = plans.pop(fut, None)
            if slot is not None:
                planned(slot)

    while True:
        collect()
        fill()
        if not slots:  # every task planned and consumed
            return
        head = slots[0]
        if (head.plan not in plans and not head.todo and not head.wants_alternatives
                and all(f.done() for f in head.chunks)
                and (head.alternatives is None or head.alternatives.done())):
            slots.popleft()
            yield head.map_index, _assembled(head)
            continue
        wait(in_flight, return_when=FIRST_COMPLETED)
    # Futures still queued when the consumer stops are cancelled by the executor's shutdown.


def _assembled(slot: _Slot) -> ScenarioResult:
    """The slot's scenario with every chunk's instances appended in state order (raises a task's error)."""
    result = slot.plan.result()
    result.pending = result.pending[:0]
    for fut in slot.chunks:
        instances, skipped = fut.result()
        result.instances.extend(instances)
        result.skipped.update(skipped)
    if slot.alternatives is not None:
        attach_alternatives(result, *slot.alternatives.result())
    return result


def scenario_indices(first_index: int, max_per_map: int, keep: Callable[[int], bool] | None = None) -> Iterator[int]:
    """The first ``max_per_map`` scenario indices from ``first_index`` on that ``keep`` accepts (all without it)."""
    indices = itertools.count(first_index)
    return itertools.islice(indices if keep is None else filter(keep, indices), max_per_map)


def scenario_tasks(n_maps: int, shapes: list[str], max_per_map: int, first_index: int = 0,
                   keep: Callable[[int], bool] | None = None) -> Iterator[tuple[int, str, int]]:
    """Round-robin over maps and shapes so that every map contributes evenly; scenario indices start at
    ``first_index`` (a test split of a training map uses an offset, so its scenario ids never collide) and, with
    ``keep`` (``split=scenario:PART``: whether an index is the part's), skip the indices it refuses."""
    for k in scenario_indices(first_index, max_per_map, keep):
        for m in range(n_maps):
            for shape in shapes:
                yield m, shape, k


def template_instances(contexts: list[MapContext], cfg: Mapping[str, Any], stats: RunStats,
                       progress: Callable[[int], None] = lambda n: None) -> Iterator[tuple[Instance, str, str, str]]:
    """Yield exactly ``num_instances`` (instance, shape, map_id, scenario_id) from template scenarios.

    A (map, shape) pair whose last ``scenario.max_failures`` scenarios in a row all failed is given up; the
    decision is taken on results in scenario order, so it does not depend on the worker count either.
    """
    shapes = shapes_of(cfg)
    wanted = int(cfg["num_instances"])
    if wanted < 1:
        raise ValueError(f"num_instances must be >= 1, got {wanted}")
    workers = int(cfg["workers"])
    max_per_map = int(cfg["scenario"]["max_per_map"])
    max_failures = int(cfg["scenario"]["max_failures"])
    failures: Counter = Counter()
    dead: set[tuple[int, str]] = set()
    per_task = states_per_task(cfg)
    executor = _executor(workers, str(cfg["start_method"]), contexts, cfg)
    produced = 0
    split = parse_split(cfg)
    keep = (lambda k: in_scenario_part(split, k)) if split is not None and split.mode == "scenario" else None
    tasks = (t for t in scenario_tasks(len(contexts), shapes, max_per_map, int(cfg["scenario"].get("first_index", 0)),
                                       keep)
             if (t[0], t[1]) not in dead)  # only saves work; correctness comes from the check below
    results = ordered_results(executor, tasks, workers, per_task, needed=lambda m, shape: (m, shape) not in dead,
                              remaining=lambda: wanted - produced, alternatives=alternatives_count(cfg) > 0)
    try:
        for map_index, result in results:
            pair = (map_index, result.shape)
            if pair in dead:
                continue
            stats.add(result)
            if not result.instances:
                failures[pair] += 1
                if failures[pair] >= max_failures:
                    dead.add(pair)
                    log.warning("giving up %s shape %s after %d failed scenarios in a row: %s", result.map_id,
                                result.shape, max_failures, dict(stats.rejections_by_map[result.map_id]))
                continue
            failures[pair] = 0
            take = result.instances[: wanted - produced]
            stats.scenarios.append(_summary(result, len(take)))
            for inst in take:
                yield inst, result.shape, result.map_id, result.scenario_id
            produced += len(take)
            progress(len(take))
            if produced >= wanted:
                return
    finally:
        if isinstance(executor, ProcessPoolExecutor):
            executor.shutdown(wait=True, cancel_futures=True)
    given_up = sorted(f"{contexts[m].map_id}:{s}" for m, s in dead)
    raise NotEnoughInstancesError(
        f"asked for num_instances={wanted} but {len(contexts)} map(s) x shapes {shapes} gave only {produced} from "
        f"{len(stats.scenarios)} accepted scenarios out of {stats.scenarios_tried} tried "
        f"(scenario.max_per_map={max_per_map}; given up after {max_failures} failures in a row: {given_up}); "
        f"rejections: {dict(stats.rejections)}. Lower num_instances, add maps, lower instances.spacing_m "
        f"(more states per path) or raise scenario.max_per_map{_split_hint(split)}."
    )


def _split_hint(split: Split | None) -> str:
    """What to change when a split's part of the maps is too small for the instances asked for."""
    if split is None:
        return ""
    share = round(split.fraction if split.part == "train" else 1.0 - split.fraction, 6)
    move = "lower" if split.part == "test" else "raise"
    if split.mode == "scenario":
        return f" (split=scenario:{split.part} keeps {share:g} of the scenarios: {move} split_fraction)"
    return (f" (split=area:{split.part} keeps about {share:g} of each map's free area, where every scenario must "
            f"fit: {move} split_fraction, e.g. 0.5, or try the other split_axis)")


def _summary(result: ScenarioResult, n_instances: int) -> dict[str, Any]:
    ex = result.executed
    assert ex is not None
    return {
        "scenario_id": result.scenario_id,
        "map_id": result.map_id,
        "shape": result.shape,
        "instances": n_instances,
        "length_m": round(ex.length_m, 3),
        "turn_deg": round(ex.turn_deg, 1),
        "deviation_m": round(ex.deviation_m, 3),
        "min_clearance_m": round(ex.min_clearance_m, 3),
    }


@dataclass(frozen=True)
class WindowFitRule:
    """The one definition of whether a sketch fits the student's window: the server's check (:func:`sketch_window_fit`)
    and the sketching page's live verdict both read these numbers (the page gets :meth:`to_json` from ``GET /api/map``).

    The window is placed by the sketch itself: the robot at the first waypoint, heading towards the sketch's point
    ``heading_m`` along it. Every waypoint must lie ``margin_m`` inside it; as the window moves with the sketch, this
    test does not change when the whole sketch is shifted. The executed path, snapped to the map's cells, moves by up
    to a cell against the sketch when the sketch is shifted by a fraction of one, so it must lie ``path_margin_m``
    inside the window less ``tolerance_m`` (one cell and the ``SHIFT_TOLERANCE_M`` an operator's hand wobbles by):
    a sketch shifted by up to that much keeps its verdict.
    """

    size_px: int
    robot_px: tuple[float, float]
    resolution_m: float
    margin_m: float
    heading_m: float
    path_margin_m: float
    tolerance_m: float

    SHIFT_TOLERANCE_M = 0.02  # a shift of the whole sketch by up to this keeps the verdict

    @classmethod
    def from_config(cls, cfg: Mapping[str, Any], resolution_m: float) -> "WindowFitRule":
        """The rule of an annotation config (``window``, ``execution.heading_window_m``) on a map of
        ``resolution_m`` metres per cell."""
        frame = window_frame(cfg)
        margin = float(cfg["window"]["margin_m"])
        return cls(frame.size, (float(frame.robot_px[0]), float(frame.robot_px[1])), float(resolution_m), margin,
                   float(cfg["execution"]["heading_window_m"]), margin / 2.0,
                   float(resolution_m) + cls.SHIFT_TOLERANCE_M)

    @property
    def frame(self) -> Any:
        return RobotFrame(self.size_px, self.robot_px)

    def to_json(self) -> dict[str, Any]:
        """The numbers the sketching page computes its live verdict from (metres, window pixels)."""
        return {"size_px": self.size_px, "robot_px": list(self.robot_px), "resolution_m": self.resolution_m,
                "margin_m": self.margin_m, "heading_m": self.heading_m, "path_margin_m": self.path_margin_m,
                "tolerance_m": round(self.tolerance_m, 6)}


@dataclass(frozen=True)
class SketchWindowFit:
    """How a sketch fits the student's window (:func:`sketch_window_fit`): the window's pose, the waypoints (indices
    from 0) less than the margin inside it and the executed path's points (map pixels) less than the path's margin
    (less the tolerance) inside it."""

    pose: Any  # spade.maps.frame.WindowPose
    outside_waypoints: list[int]
    outside_points: np.ndarray

    @property
    def fits(self) -> bool:
        return not self.outside_waypoints and not len(self.outside_points)


def sketch_window_fit(waypoints_px: np.ndarray, executed_px: np.ndarray | None, rule: WindowFitRule
                      ) -> SketchWindowFit:
    """Where an operator's sketch (map pixels) puts the student's window, and what of it lies outside, by
    :class:`WindowFitRule` (the page's ``sketchWindow`` computes the same from the rule's JSON)."""
    res = rule.resolution_m
    frame = rule.frame
    wp = np.asarray(waypoints_px, dtype=np.float64)
    steps = np.linalg.norm(np.diff(wp, axis=0), axis=1)
    arc = np.concatenate([[0.0], np.cumsum(steps)])
    reach = min(rule.heading_m / res, float(arc[-1]))
    k = int(np.clip(np.searchsorted(arc, reach, side="right") - 1, 0, len(wp) - 2))
    t = 0.0 if steps[k] == 0 else (reach - arc[k]) / steps[k]
    ahead = wp[k] + t * (wp[k + 1] - wp[k]) - wp[0]
    pose = frame.place(wp[0], float(np.arctan2(ahead[1], ahead[0])))

    def outside(points: np.ndarray, margin: float) -> np.ndarray:
        local = pose.to_window(points)
        return ((local < margin) | (local > frame.size - 1 - margin)).any(axis=1)

    bad_points = np.zeros((0, 2))
    if executed_px is not None and len(executed_px):
        pts = np.asarray(executed_px, dtype=np.float64)
        bad_points = pts[outside(pts, max(0.0, rule.path_margin_m - rule.tolerance_m) / res)]
    return SketchWindowFit(pose, np.flatnonzero(outside(wp, rule.margin_m / res)).tolist(), bad_points)


def execute_operator_sketch(ctx: MapContext, shape: str, waypoints_px: Any, cfg: Mapping[str, Any]) -> ExecutedPath:
    """Execute one operator sketch (map pixel waypoints) and apply every check of :func:`sketch_instances`;
    raise :class:`Rejection` when one fails (``spade.sketching`` executes the browser's sketches with it). The
    window check is :func:`sketch_window_fit`'s (the window the sketching page draws)."""
    rule = WindowFitRule.from_config(cfg, ctx.costmap.resolution)
    executed = execute_sketch(ctx.costmap, waypoints_px, densify(waypoints_px, 0.5), SHAPES[shape], cfg["execution"])
    fit = sketch_window_fit(waypoints_px, executed.points, rule)
    if not fit.fits:
        named = ", ".join(f"#{i + 1}" for i in fit.outside_waypoints)
        path_margin = max(0.0, rule.path_margin_m - rule.tolerance_m)
        where = (f"waypoint{'s' * (len(fit.outside_waypoints) > 1)} {named} less than {rule.margin_m:g} m inside"
                 if named else f"{len(fit.outside_points)} points of the executed path less than "
                               f"{path_margin:g} m inside")
        raise Rejection("window", f"{where} the {rule.size_px} px robot-frame window (robot at the first waypoint, "
                                  "heading along the sketch)", executed.points)
    return executed


def sketch_instances(ctx: MapContext, sketches: list[tuple[str, str, Any]], cfg: Mapping[str, Any], stats: RunStats,
                     progress: Callable[[int], None] = lambda n: None) -> Iterator[tuple[Instance, str, str, str]]:
    """Instances of operator sketches ``(name, shape, waypoints_px)`` on one map; a rejected sketch is counted
    and logged, never silently dropped."""
    for k, (name, shape, waypoints_px) in enumerate(sketches):
        result = ScenarioResult(f"{ctx.map_id}/{name}", ctx.map_id, shape, k)
        try:
            executed = execute_operator_sketch(ctx, shape, waypoints_px, cfg)
        except Rejection as rej:
            result.rejections[rej.reason] += 1
            stats.add(result)
            log.warning("sketch %s rejected: %s", result.scenario_id, rej)
            continue
        result.executed = executed
        result.instances = instances_along(ctx, executed, cfg, result.skipped)
        if alternatives_count(cfg):
            log.warning("alternatives.count=%s is ignored for operator sketches: alternatives are draws of the "
                        "template generator, which a sketch does not come from", cfg["alternatives"]["count"])
        stats.add(result)
        stats.scenarios.append(_summary(result, len(result.instances)))
        for inst in result.instances:
            yield inst, shape, ctx.map_id, result.scenario_id
        progress(len(result.instances))


def write_dataset(out_dir: str | Path, items: Iterable[tuple[Instance, str, str, str]], cfg: Mapping[str, Any],
                  extra: Mapping[str, Any] | Callable[[], Mapping[str, Any]], resolution: float) -> int:
    """Write instances with :class:`spade.data.DatasetWriter`; ``extra`` (or what it returns once every item is
    written) goes into the manifest. Returns the number of instances."""
    size = int(cfg["window"]["size_px"])
    alternatives = alternatives_count(cfg) if _expected(cfg) is not None else 0
    with DatasetWriter(out_dir, image_size=(size, size), resolution=resolution, num_waypoints=int(cfg["num_waypoints"]),
                       generator_config=dict(cfg), overwrite=bool(cfg.get("overwrite", False)),
                       expected_instances=_expected(cfg), alternatives=alternatives,
                       alternatives_info=_alternatives_info(cfg) if alternatives else None) as writer:
        for inst, shape, map_id, scenario_id in items:
            writer.add(inst.occupancy, inst.start, inst.goal, inst.path, inst.waypoints, shape, map_id, scenario_id,
                       inst.pose, alternatives=inst.alternatives)
        info = extra() if callable(extra) else extra
        if writer.count == 0:  # raised inside the block so that no empty dataset is left behind
            raise NotEnoughInstancesError(f"no instance was produced for {out_dir}: {dict(info)}")
        for key, value in info.items():
            writer.set_extra(key, value)
        count = writer.count
    return count


def _alternatives_info(cfg: Mapping[str, Any]) -> dict[str, Any]:
    """The manifest's record of how the alternatives were drawn."""
    return {"version": ALTERNATIVES_VERSION, "estimator": ESTIMATOR,
            "settings": AlternativesSettings.from_cfg(cfg.get("alternatives")).to_json()}


def _expected(cfg: Mapping[str, Any]) -> int | None:
    """The instances a template run will write (None for sketches and imports, whose count is not known ahead)."""
    if cfg.get("sketches") or (cfg.get("rosbag") or {}).get("paths") or (cfg.get("skipp") or {}).get("root"):
        return None
    try:
        return int(cfg["num_instances"])
    except (KeyError, TypeError, ValueError):
        return None


def build_contexts(sources: list[Any], cfg: Mapping[str, Any]) -> list[MapContext]:
    """Costmaps and goal areas of every map (raises :class:`NoFreeAreaError` for a map too cluttered)."""
    return [prepare_map(s.map_id, s.map.grid, s.map.resolution, cfg, s.map.origin) for s in sources]
