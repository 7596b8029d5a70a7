"""Last-mile delivery scenarios: a goal in open free space, a sketch ending on it, its execution and the
instances rasterised along it.

Every scenario draws its randomness from its own generator, seeded by (dataset seed, map id, shape, scenario
index) through ``numpy.random.SeedSequence``, so scenarios can be computed in any order and in any number of
processes without changing a byte of the output. Below the scenario, each robot state's instance is a pure
function of the map, the executed path and the state's index: :func:`plan_scenario` finds the accepted path (and
its first instance), and the remaining states can be rasterised in chunks by any number of processes
(:func:`rasterise_states`), which is how the pipeline keeps every worker busy on a set of few scenarios.
"""

from __future__ import annotations

import dataclasses
import zlib
from collections import Counter
from dataclasses import dataclass, field
from typing import Any, Iterable, Mapping

import numpy as np
from scipy.cluster.vq import kmeans2

from spade.annotation.alternative_demonstrations import AlternativesSettings, scenario_alternatives
from spade.annotation.execution import ExecutedPath, Rejection, execute_sketch
from spade.annotation.split import CROSSING, AreaLine, area_line, parse_split
from spade.annotation.templates import SHAPES, check_shape, place_template, sample_template, sketch_fits
from spade.data.rasterize import Instance, fits_robot_frame, robot_instance, state_indices
from spade.maps.costmap import Costmap, build_costmap
from spade.maps.frame import RobotFrame, yaw_from_heading
from spade.utils.errors import UserError


class NoFreeAreaError(UserError, ValueError):
    """A map has no free cell with the clearance a scenario's goal needs."""


def stable_hash(text: str) -> int:
    """A process-independent 32-bit hash of ``text`` (Python's ``hash`` is salted per process)."""
    return zlib.crc32(text.encode("utf-8"))


def scenario_rng(seed: int, map_id: str, shape: str, index: int) -> np.random.Generator:
    """The generator of one scenario, independent of every other scenario's."""
    return np.random.default_rng(np.random.SeedSequence([int(seed), stable_hash(map_id), stable_hash(shape),
                                                         int(index)]))


def goal_clearance_m(cfg: Mapping[str, Any]) -> float:
    """Clearance a goal needs: ``scenario.goal_clearance_m`` or, when null, robot radius + inflation radius."""
    value = cfg["scenario"].get("goal_clearance_m")
    if value is None:
        return float(cfg["robot"]["radius_m"]) + float(cfg["robot"]["inflation_radius_m"])
    return float(value)


@dataclass
class MapContext:
    """What scenarios need from one map, computed once: the inflated costmap and goal areas."""

    map_id: str
    costmap: Costmap
    goal_cells: np.ndarray  # (M, 2) int (col, row) cells with enough clearance
    goal_area: np.ndarray  # (M,) area label of each goal cell
    n_areas: int
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)  # the ROS map origin (of an axis-aligned map)
    line: AreaLine | None = None  # split=area:PART: the side of the map this part's scenarios keep to

    def world_pose(self, x_px: float, y_px: float, heading: float) -> tuple[float, float, float]:
        """(x, y, yaw) in map metres of a robot at map pixel (x_px, y_px) with map-pixel heading ``heading``."""
        res, height = self.costmap.resolution, self.costmap.grid.shape[0]
        x = self.origin[0] + (x_px + 0.5) * res
        y = self.origin[1] + (height - 1 - y_px + 0.5) * res
        return float(x), float(y), yaw_from_heading(heading)


def window_frame(cfg: Mapping[str, Any]) -> RobotFrame:
    """The robot frame of the configured window (``window.size_px``)."""
    return RobotFrame.for_size(int(cfg["window"]["size_px"]))


def prepare_map(map_id: str, grid: np.ndarray, resolution: float, cfg: Mapping[str, Any],
                origin: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> MapContext:
    """Inflate the map and split its goal candidates into spatially separate areas (k-means on cell
    positions), so that consecutive scenarios of a map land in different parts of it. With ``split=area:PART``
    the goal candidates are those on the part's side of the map's split line (:mod:`spade.annotation.split`)."""
    costmap = build_costmap(grid, resolution, cfg["robot"], float(cfg["execution"]["cost_weight"]))
    need_px = goal_clearance_m(cfg) / resolution
    rows, cols = np.nonzero(costmap.clearance_px >= need_px)
    split = parse_split(cfg)
    line = area_line(map_id, grid, resolution, origin, split) if split is not None and split.mode == "area" else None
    if line is not None and len(rows):
        keep = line.on_side(np.stack([cols, rows], axis=1))
        if not keep.any():
            raise NoFreeAreaError(
                f"map {map_id!r} has no free cell with {goal_clearance_m(cfg):.2f} m clearance for a goal on the "
                f"{line.part} side of its split line ({line.to_json()['part_side']}, split_fraction="
                f"{split.fraction}); move the line with split_fraction or split_axis, or remove the map from maps="
            )
        rows, cols = rows[keep], cols[keep]
    if len(rows) == 0:
        best = float(costmap.clearance_px.max()) * resolution
        raise NoFreeAreaError(
            f"map {map_id!r} ({grid.shape[1]} x {grid.shape[0]} px at {resolution} m/px, "
            f"{int((grid == 1).sum())} free cells) has no free cell with {goal_clearance_m(cfg):.2f} m clearance "
            f"for a goal; its most open cell has {best:.2f} m. Remove the map from maps= or lower "
            f"scenario.goal_clearance_m / robot.inflation_radius_m."
        )
    cells = np.stack([cols, rows], axis=1)
    n_areas = int(min(int(cfg["scenario"]["areas_per_map"]), len(cells)))
    rng = np.random.default_rng(np.random.SeedSequence([stable_hash(map_id), 7]))
    sample = cells[rng.choice(len(cells), size=min(len(cells), 4000), replace=False)].astype(np.float64)
    if n_areas > 1:
        centroids, _ = kmeans2(sample, n_areas, minit="++", seed=rng)
        labels = np.argmin(((cells[:, None, :] - centroids[None]) ** 2).sum(-1), axis=1)
        # Order areas along the map so area k is reproducible and empty areas are dropped.
        used = np.unique(labels)
        order = used[np.lexsort((centroids[used, 0], centroids[used, 1]))]
        remap = np.full(n_areas, -1)
        remap[order] = np.arange(len(order))
        labels = remap[labels]
        n_areas = len(order)
    else:
        labels = np.zeros(len(cells), dtype=np.int64)
    origin3 = tuple(float(v) for v in origin)
    return MapContext(map_id, costmap, cells, labels, n_areas, origin3, line)  # type: ignore[arg-type]


def costmap_context(map_id: str, grid: np.ndarray, resolution: float, cfg: Mapping[str, Any],
                    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> MapContext:
    """A context with the costmap only, for sketches whose goals are given (operator sketch files)."""
    costmap = build_costmap(grid, resolution, cfg["robot"], float(cfg["execution"]["cost_weight"]))
    return MapContext(map_id, costmap, np.zeros((0, 2), dtype=np.int64), np.zeros(0, dtype=np.int64), 0,
                      tuple(float(v) for v in origin))  # type: ignore[arg-type]


@dataclass
class ScenarioResult:
    """The outcome of one scenario: its instances (empty if every attempt was rejected) and the rejections."""

    scenario_id: str
    map_id: str
    shape: str
    index: int
    rejections: Counter = field(default_factory=Counter)
    skipped: Counter = field(default_factory=Counter)  # robot states along an accepted path left out, by reason
    instances: list[Instance] = field(default_factory=list)
    executed: ExecutedPath | None = None
    sketch: np.ndarray | None = None  # keypoints, map pixel coords
    # indices into executed.points of the robot states still to rasterise (plan_scenario leaves them to workers)
    pending: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    alternative_stats: Counter = field(default_factory=Counter)  # the alternatives sampler's counters


def scenario_area(ctx: MapContext, index: int, cfg: Mapping[str, Any]) -> int:
    """Goal area of scenario ``index``: cycles through ``scenario.areas`` (all areas when null), so that a train
    and a test split of one map can use disjoint parts of it."""
    areas = cfg["scenario"].get("areas")
    if areas is None:
        return index % ctx.n_areas
    areas = [int(a) for a in areas]
    bad = [a for a in areas if not 0 <= a < ctx.n_areas]
    if bad or not areas:
        raise ValueError(f"scenario.areas={areas} on map {ctx.map_id!r}: areas are numbered 0..{ctx.n_areas - 1} "
                         f"(scenario.areas_per_map={cfg['scenario']['areas_per_map']}); use indices in that range")
    return areas[index % len(areas)]


def _placement(ctx: MapContext, shape: str, goal: np.ndarray, cfg: Mapping[str, Any], rng: np.random.Generator,
               frame: RobotFrame, margin_px: float) -> tuple[np.ndarray, np.ndarray] | str:
    """Try ``scenario.headings_per_goal`` sampled templates at ``goal``; return the first whose ideal curve lies
    on free space with ``scenario.sketch_clearance_m``, fits the robot-frame window of its start and (with an
    area split) lies on its part's side of the map; else the rejection reason: ``split_crossing`` when a template
    failed only for crossing the split line, ``placement`` otherwise."""
    res = ctx.costmap.resolution
    need = float(cfg["scenario"]["sketch_clearance_m"]) / res
    crossed = False
    for _ in range(int(cfg["scenario"]["headings_per_goal"])):
        template = sample_template(shape, cfg["template"], rng)
        keypoints, dense = place_template(template, goal, res)
        if not sketch_fits(ctx.costmap, dense, frame, margin_px, need):
            continue
        if ctx.line is not None and not ctx.line.holds(dense):
            crossed = True
            continue
        return keypoints, dense
    return CROSSING if crossed else "placement"


def state_indices_along(ctx: MapContext, executed: ExecutedPath, cfg: Mapping[str, Any]) -> np.ndarray:
    """Indices into ``executed.points`` of the robot states sampled every ``instances.spacing_m`` along it."""
    res = ctx.costmap.resolution
    return state_indices(len(executed.points), executed.step_px, float(cfg["instances"]["spacing_m"]) / res,
                         float(cfg["instances"]["min_remaining_m"]) / res)


def rasterise_states(ctx: MapContext, points: np.ndarray, indices: Iterable[int], cfg: Mapping[str, Any],
                     skipped: Counter | None = None, first_only: bool = False) -> tuple[list[Instance], int]:
    """Instances of the robot states ``points[i]`` for ``i`` in ``indices`` (an executed path's points), in order.

    A state is skipped, and counted in ``skipped``, when its remaining path leaves the window
    (``outside_window``) or a path pixel falls on a cell the conservative rotation of the occupancy marks as
    non-free (``path_off_free``: a path that hugs a wall, at the window's pixel size). Every state is a pure
    function of the map, the path and its index, so the states of one path can be rasterised in any chunks, in
    any process. Returns the instances and how many states were looked at (with ``first_only``, up to and
    including the first that fits).
    """
    res = ctx.costmap.resolution
    frame = window_frame(cfg)
    margin = float(cfg["window"]["margin_m"]) / res
    disc = float(cfg["instances"]["disc_radius_m"]) / res
    k = int(cfg["num_waypoints"])
    skipped = skipped if skipped is not None else Counter()
    out: list[Instance] = []
    seen = 0
    for i in indices:
        seen += 1
        inst = robot_instance(ctx.costmap.grid, points[int(i):], frame, margin, disc, k, to_world=ctx.world_pose)
        if inst is None:
            skipped["outside_window"] += 1
            continue
        if (inst.occupancy[inst.path] != 1).any():
            skipped["path_off_free"] += 1
            continue
        out.append(dataclasses.replace(inst, state_index=int(i)))
        if first_only:
            break
    return out, seen


def instances_along(ctx: MapContext, executed: ExecutedPath, cfg: Mapping[str, Any],
                    skipped: Counter | None = None) -> list[Instance]:
    """Rasterise robot states every ``instances.spacing_m`` along an executed path, each in its robot frame
    (:func:`rasterise_states`: states that do not fit are counted in ``skipped``)."""
    return rasterise_states(ctx, executed.points, state_indices_along(ctx, executed, cfg), cfg, skipped)[0]


def plan_scenario(ctx: MapContext, shape: str, index: int, cfg: Mapping[str, Any]) -> ScenarioResult:
    """Scenario ``index`` of ``shape`` on one map, up to its first instance: up to ``scenario.max_attempts``
    goal/sketch draws, each executed and checked; the first accepted one whose path has a state that fits is
    kept, with that state's instance in ``instances`` and the later states in ``pending``.

    :func:`complete_scenario` (or :func:`rasterise_states` on chunks of ``pending``, in other processes) adds the
    rest; the outcome is :func:`generate_scenario`'s whatever the split, since an attempt is accepted exactly
    when one of its states fits and every state is a pure function of the path.
    """
    check_shape(shape)
    result = ScenarioResult(f"{ctx.map_id}/{shape}{index:03d}", ctx.map_id, shape, index)
    rng = scenario_rng(int(cfg["seed"]), ctx.map_id, shape, index)
    res = ctx.costmap.resolution
    frame = window_frame(cfg)
    margin = float(cfg["window"]["margin_m"]) / res
    in_area = np.flatnonzero(ctx.goal_area == scenario_area(ctx, index, cfg))
    for _ in range(int(cfg["scenario"]["max_attempts"])):
        goal = ctx.goal_cells[in_area[rng.integers(len(in_area))]].astype(np.float64)
        placed = _placement(ctx, shape, goal, cfg, rng, frame, margin)
        if isinstance(placed, str):
            result.rejections[placed] += 1
            continue
        keypoints, dense = placed
        try:
            executed = execute_sketch(ctx.costmap, keypoints, dense, SHAPES[shape], cfg["execution"])
        except Rejection as rej:
            result.rejections[rej.reason] += 1
            continue
        if ctx.line is not None and not ctx.line.holds(executed.points):
            result.rejections[CROSSING] += 1  # the driven path leaves its part of the map
            continue
        if not fits_robot_frame(executed.points, frame, margin):
            result.rejections["window"] += 1
            continue
        states = state_indices_along(ctx, executed, cfg)
        first, seen = rasterise_states(ctx, executed.points, states, cfg, result.skipped, first_only=True)
        if not first:
            result.rejections["no_state_fits"] += 1
            continue
        result.executed, result.sketch = executed, keypoints
        result.instances, result.pending = first, states[seen:]
        return result
    result.rejections["scenario_failed"] += 1
    return result


def alternatives_rng(seed: int, map_id: str, shape: str, index: int) -> np.random.Generator:
    """The generator of one scenario's alternative demonstrations (independent of the scenario's own draws)."""
    return np.random.default_rng(np.random.SeedSequence([int(seed), stable_hash(map_id), stable_hash(shape),
                                                         int(index), stable_hash("alternatives")]))


def plan_alternatives(ctx: MapContext, result: ScenarioResult, cfg: Mapping[str, Any]
                      ) -> tuple[dict[int, np.ndarray], dict[str, int]]:
    """Alternative demonstrations of every robot state of a planned scenario (``cfg.alternatives``; see
    :mod:`spade.annotation.alternative_demonstrations`): {state index: (k, num_waypoints, 2)} and the sampler's
    counters."""
    settings = AlternativesSettings.from_cfg(cfg.get("alternatives"))
    if not settings.wanted(result.shape) or result.executed is None or result.sketch is None:
        return {}, {}
    states = state_indices_along(ctx, result.executed, cfg)
    rng = alternatives_rng(int(cfg["seed"]), ctx.map_id, result.shape, result.index)
    return scenario_alternatives(ctx.costmap, result.shape, result.sketch[-1], result.executed.points, states, cfg,
                                 settings, rng)


def complete_scenario(ctx: MapContext, result: ScenarioResult, cfg: Mapping[str, Any]) -> ScenarioResult:
    """Rasterise a planned scenario's ``pending`` states in this process (see :func:`plan_scenario`), with their
    alternative demonstrations when ``cfg.alternatives.count`` > 0."""
    if result.executed is not None and len(result.pending):
        more, _ = rasterise_states(ctx, result.executed.points, result.pending, cfg, result.skipped)
        result.instances.extend(more)
    result.pending = np.zeros(0, dtype=np.int64)
    alternatives, counters = plan_alternatives(ctx, result, cfg)
    attach_alternatives(result, alternatives, counters)
    return result


def attach_alternatives(result: ScenarioResult, alternatives: dict[int, np.ndarray], counters: Mapping[str, int]
                        ) -> None:
    """Give each instance of ``result`` its state's alternatives (none computed: left as they are)."""
    if not counters:
        return
    result.alternative_stats.update(counters)
    result.instances = [dataclasses.replace(inst, alternatives=alternatives.get(inst.state_index))
                        for inst in result.instances]


def generate_scenario(ctx: MapContext, shape: str, index: int, cfg: Mapping[str, Any]) -> ScenarioResult:
    """Scenario ``index`` of ``shape`` on one map: up to ``scenario.max_attempts`` goal/sketch draws, each
    executed and checked; the first accepted one yields the instances (:func:`plan_scenario`, then
    :func:`complete_scenario`)."""
    return complete_scenario(ctx, plan_scenario(ctx, shape, index, cfg), cfg)
