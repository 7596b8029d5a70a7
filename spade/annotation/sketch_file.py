"""Operators' own sketches: a YAML file of waypoints drawn on a map, one entry per scenario.

Format (waypoints in map-frame metres, in driving order, the last one is the goal)::

    map: maps/my_site.yaml        # a ROS map yaml (relative to this file) or a generator spec like office:2
    scenarios:
      - shape: L                  # L or U: the manoeuvre the sketch demonstrates (checked after execution)
        name: dock_a              # optional; default {shape}{k:03d}
        waypoints: [[1.0, 2.0], [3.0, 2.0], [3.6, 2.4], [3.8, 3.0], [3.8, 4.5]]
      - shape: U
        waypoints: [...]
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from spade.annotation.sources import parse_procedural
from spade.annotation.templates import check_shape
from spade.utils.errors import UserError


class SketchFileError(UserError, ValueError):
    """A sketch file is malformed; the message names the entry and the fix."""


@dataclass(frozen=True)
class Sketch:
    name: str
    shape: str
    waypoints_m: np.ndarray  # (N, 2) map-frame metres


@dataclass(frozen=True)
class SketchFile:
    path: Path
    map: str  # yaml path (resolved) or generator spec
    sketches: list[Sketch]


def load_sketch_file(path: str | Path) -> SketchFile:
    """Parse and validate a sketch file (the waypoints are checked against the map later, once it is loaded)."""
    path = Path(path).expanduser()
    if not path.is_file():
        raise FileNotFoundError(f"sketch file {path} does not exist")
    try:
        doc = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:  # a syntax error, or a tag that would build a Python object (refused, not run)
        problem = str(getattr(exc, "problem", None) or exc).splitlines()[0]
        mark = getattr(exc, "problem_mark", None)
        where = f" (line {mark.line + 1})" if mark is not None else ""
        raise SketchFileError(f"{path}: not a plain YAML sketch file{where}: {problem}; write plain YAML with keys "
                              "'map' and 'scenarios' (no !!python tags)") from None
    example = "{map: my_map.yaml, scenarios: [{shape: L, waypoints: [[0.0, 0.0], [2.0, 0.0], [2.0, 1.5]]}]}"
    if not isinstance(doc, dict) or "map" not in doc or "scenarios" not in doc:
        raise SketchFileError(f"{path}: expected keys 'map' and 'scenarios', e.g. {example}")
    map_ref = str(doc["map"])
    if parse_procedural(map_ref) is None:
        map_path = Path(map_ref).expanduser()
        if not map_path.is_absolute():
            map_path = (path.parent / map_path).resolve()
        if not map_path.is_file():
            raise SketchFileError(f"{path}: map {map_ref!r} not found (looked at {map_path})")
        map_ref = str(map_path)
    entries = doc["scenarios"]
    if not isinstance(entries, list) or not entries:
        raise SketchFileError(f"{path}: 'scenarios' must be a non-empty list, e.g. {example}")
    sketches, names = [], set()
    counts: dict[str, int] = {}
    for i, entry in enumerate(entries):
        if not isinstance(entry, dict) or "shape" not in entry or "waypoints" not in entry:
            raise SketchFileError(f"{path}: scenario #{i} needs 'shape' and 'waypoints', e.g. {example}")
        shape = check_shape(str(entry["shape"]))
        wp = np.asarray(entry["waypoints"], dtype=np.float64)
        if wp.ndim != 2 or wp.shape[1] != 2 or len(wp) < 2 or not np.isfinite(wp).all():
            raise SketchFileError(f"{path}: scenario #{i} waypoints must be a list of >= 2 [x, y] pairs in metres, "
                                  f"got array of shape {wp.shape}")
        k = counts.get(shape, 0)
        counts[shape] = k + 1
        name = str(entry.get("name", f"{shape}{k:03d}"))
        if name in names:
            raise SketchFileError(f"{path}: scenario name {name!r} is used twice; names must be unique")
        names.add(name)
        sketches.append(Sketch(name, shape, wp))
    return SketchFile(path, map_ref, sketches)


def sketch_to_pixels(sketch: Sketch, occupancy_map: Any) -> np.ndarray:
    """Waypoints in map pixel coordinates; raise if any lies outside the map, with the numbers."""
    px = occupancy_map.world_to_pixel(sketch.waypoints_m)
    h, w = occupancy_map.grid.shape
    outside = (px[:, 0] < -0.5) | (px[:, 0] > w - 0.5) | (px[:, 1] < -0.5) | (px[:, 1] > h - 0.5)
    if outside.any():
        i = int(np.flatnonzero(outside)[0])
        x0, y0 = occupancy_map.origin[0], occupancy_map.origin[1]
        x1, y1 = x0 + w * occupancy_map.resolution, y0 + h * occupancy_map.resolution
        raise SketchFileError(
            f"sketch {sketch.name!r}: waypoint #{i} ({sketch.waypoints_m[i, 0]:.2f}, {sketch.waypoints_m[i, 1]:.2f}) m "
            f"lies outside map {getattr(occupancy_map, 'name', '?')!r}, which spans x [{x0:.2f}, {x1:.2f}] m, "
            f"y [{y0:.2f}, {y1:.2f}] m; waypoints are map-frame metres (the frame of the map yaml's origin)"
        )
    return px


def densify(points: np.ndarray, step: float) -> np.ndarray:
    """The polyline through ``points`` sampled every ``step`` (same units), vertices kept."""
    out = [points[:1]]
    for a, b in zip(points[:-1], points[1:]):
        n = max(1, int(np.ceil(np.linalg.norm(b - a) / step)))
        t = np.linspace(0.0, 1.0, n + 1)[1:, None]
        out.append(a + t * (b - a))
    return np.concatenate(out)
