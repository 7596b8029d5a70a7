"""Whole scenarios from a test set: the map, the demonstration's start pose and goal, the demonstration itself.

A test set stores robot states along each demonstrated scenario, each as a robot-frame window with the remaining
path in window pixels and the robot's pose in its map. The scenario's *first* state (the one with the longest
remaining path) holds the whole demonstration from where the robot started: its waypoints, mapped back through
its pose (:meth:`spade.maps.frame.WindowPose.to_map`), are the demonstration in map metres; its alternatives
(where the test set has them, :mod:`spade.annotation.alternative_demonstrations`) the other paths an operator
could have drawn from the same state. The map comes back from the manifest's record of its source (a procedural spec such as
``warehouse:3``, or a ROS map yaml), loaded at the dataset's resolution exactly as the annotation tool loaded it.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from spade.maps.costmap import Costmap, build_costmap
from spade.maps.frame import RobotFrame, heading_from_yaw
from spade.maps.occupancy import OccupancyMap
from spade.utils.errors import UserError
from spade.annotation.sources import load_map_sources, parse_procedural

__all__ = ["Scenario", "ScenarioError", "load_scenarios", "scenario_starts"]

# The annotation tool's robot and costmap defaults (conf/annotate.yaml), for manifests that do not record them.
DEFAULT_ROBOT = {"radius_m": 0.105, "inflation_radius_m": 0.55, "cost_scaling_factor": 3.0}
DEFAULT_COST_WEIGHT = 4.0


class ScenarioError(UserError, ValueError):
    """A test set whose scenarios cannot be rebuilt (no map record, a map that cannot be found)."""


@dataclass
class Scenario:
    """One demonstrated scenario on its map, in map-frame metres.

    ``start``: the robot's pose (x, y, yaw) at the demonstration's first state; ``goal``: (x, y), the
    demonstration's last point; ``demonstration``: (K, 2) from the start to the goal; ``alternatives``: (A, K, 2)
    other demonstrations from the same state (A = 0 where the test set has none); ``costmap``: the map inflated for
    the robot the demonstrations were made for (its lethal cells are a collision); ``radius_boundary_m``: the
    radius between the generator's sharp and wide turns of this shape (None where unknown).
    """

    scenario_id: str
    map_id: str
    shape: str
    map: OccupancyMap
    costmap: Costmap
    start: np.ndarray
    goal: np.ndarray
    demonstration: np.ndarray
    alternatives: np.ndarray = field(default_factory=lambda: np.zeros((0, 0, 2)))
    radius_boundary_m: float | None = None
    instance: int = -1  # the test set's index of the first state

    @property
    def length_m(self) -> float:
        return float(np.linalg.norm(np.diff(self.demonstration, axis=0), axis=1).sum())

    def plausible(self) -> np.ndarray:
        """(1 + A, K, 2): the demonstration and its alternatives."""
        if len(self.alternatives) == 0:
            return self.demonstration[None]
        return np.concatenate([self.demonstration[None], self.alternatives])


def scenario_starts(scenario_ids: Sequence[str], waypoints: np.ndarray, indices: Iterable[int] | None = None
                    ) -> list[int]:
    """The index of each scenario's first state among ``indices`` (default: all): the state with the longest
    remaining path (ties: the earliest index), in the order the scenarios first appear."""
    best: dict[str, tuple[float, int]] = {}
    order: list[str] = []
    for i in (range(len(scenario_ids)) if indices is None else indices):
        i = int(i)
        sid = scenario_ids[i]
        length = float(np.linalg.norm(np.diff(np.asarray(waypoints[i], np.float64), axis=0), axis=1).sum())
        if sid not in best:
            order.append(sid)
            best[sid] = (length, i)
        elif length > best[sid][0]:
            best[sid] = (length, i)
    return [best[s][1] for s in order]


def _map_records(manifest: Any) -> dict[str, dict[str, Any]]:
    maps = (manifest.extra or {}).get("maps") or []
    if not maps:
        raise ScenarioError(
            f"{manifest.root}: the manifest records no maps (extra.maps), so its scenarios cannot be driven: closed "
            "loop needs a test set made by python -m spade.annotate from templates on maps= (not sketches, rosbags or "
            "SKIPP). Regenerate the test set with this SPADE"
        )
    return {str(m["map_id"]): dict(m) for m in maps}


def _load_map(record: dict[str, Any], resolution: float, root: Path) -> OccupancyMap:
    source = str(record["source"])
    if parse_procedural(source) is None and not Path(source).expanduser().is_file():
        raise ScenarioError(
            f"{root}: map {record['map_id']!r} was made from {source}, which does not exist here; closed loop needs "
            "the map itself. Set SPADE_MAPS_DIR (or restore the file) as when the test set was generated"
        )
    return load_map_sources([source], resolution)[0].map


def _radius_boundary(generator: dict[str, Any], shape: str) -> float | None:
    bands = (((generator.get("template") or {}).get(shape) or {}).get("radius_m")) or {}
    try:
        return 0.5 * (float(bands["sharp"][1]) + float(bands["wide"][0]))
    except (KeyError, TypeError, IndexError, ValueError):
        return None


def load_scenarios(dataset: Any, indices: Sequence[int] | None = None, limit: int | None = None) -> list[Scenario]:
    """The scenarios of a :class:`~spade.data.path_dataset.PathDataset` (restricted to
    ``indices``, e.g. a test subset), at most ``limit`` (the first ones), each from its first state (module
    docstring)."""
    manifest = dataset.manifest
    records = _map_records(manifest)
    frame = RobotFrame.from_json(manifest.frame)
    arrays = dataset._arrays()
    ids = dataset.labels("scenario_id")
    starts = scenario_starts(ids, arrays["waypoints"], indices)
    if limit is not None:
        starts = starts[: int(limit)]
    generator = manifest.generator or {}
    robot = {**DEFAULT_ROBOT, **(generator.get("robot") or {})}
    weight = float((generator.get("execution") or {}).get("cost_weight", DEFAULT_COST_WEIGHT))
    maps: dict[str, tuple[OccupancyMap, Costmap]] = {}
    out = []
    for i in starts:
        map_id = manifest.label("map_id", i)
        if map_id not in records:
            raise ScenarioError(f"{manifest.root}: instance {i} is on map {map_id!r}, which the manifest's maps do not "
                                "record; regenerate the test set")
        if map_id not in maps:
            m = _load_map(records[map_id], manifest.resolution, manifest.root)
            maps[map_id] = (m, build_costmap(m.grid, m.resolution, robot, weight))
        m, costmap = maps[map_id]
        pose = np.asarray(arrays["pose"][i], np.float64)
        window = frame.place(m.world_to_pixel(pose[:2]), heading_from_yaw(float(pose[2])))
        demo = m.pixel_to_world(window.to_map(np.asarray(arrays["waypoints"][i], np.float64)))
        alts = np.zeros((0, len(demo), 2))
        if manifest.alternatives:
            raw = np.asarray(arrays["alternatives"][i], np.float64)
            raw = raw[np.isfinite(raw).all(axis=(1, 2))]
            if len(raw):
                alts = m.pixel_to_world(window.to_map(raw))
        shape = manifest.label("shape", i)
        out.append(Scenario(manifest.label("scenario_id", i), map_id, shape, m, costmap, pose.copy(),
                            demo[-1].copy(), demo, alts, _radius_boundary(generator, shape), int(i)))
    return out
