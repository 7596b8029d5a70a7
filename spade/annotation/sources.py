"""Resolution of the ``maps=`` setting into occupancy maps with stable ids.

``maps`` may be a folder (every ``*.yaml`` below it, recursively, in sorted order), one map yaml, a
procedural generator spec ``kind:seed`` (e.g. ``warehouse:3``), or a list mixing those.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable

from spade.maps import GENERATORS, OccupancyMap, generate_map, load_ros_map


@dataclass(frozen=True)
class MapSource:
    """A map ready for annotation: ``map_id`` is the id stored with its instances."""

    map_id: str
    source: str  # the yaml path or the generator spec it came from
    map: OccupancyMap


def parse_procedural(spec: str) -> tuple[str, int] | None:
    """``"warehouse:3"`` -> ("warehouse", 3); None when ``spec`` is not a generator spec."""
    kind, sep, seed = spec.partition(":")
    if not sep or kind not in GENERATORS:
        return None
    try:
        return kind, int(seed)
    except ValueError:
        raise ValueError(f"procedural map spec {spec!r}: its seed {seed!r} is not an integer; give an integer seed "
                         f"after ':', e.g. {kind}:3") from None


def procedural_id(kind: str, seed: int) -> str:
    return f"{kind}-s{seed}"


def _items(maps: Any) -> list[str]:
    if maps is None:
        raise ValueError("maps= is empty: give a folder of ROS map yamls, a list of yaml paths or specs like "
                         f"[warehouse:1,office:2] (kinds: {sorted(GENERATORS)})")
    if isinstance(maps, (str, Path)):
        return [str(maps)]
    return [str(m) for m in maps]


def expand_map_specs(maps: Any) -> list[str]:
    """Expand folders into their yaml files; keep generator specs and yaml paths as they are."""
    out: list[str] = []
    for item in _items(maps):
        if parse_procedural(item) is not None:
            out.append(item)
            continue
        path = Path(item).expanduser()
        if path.is_dir():
            found = sorted(str(p) for p in path.rglob("*.yaml"))
            if not found:
                raise FileNotFoundError(f"maps folder {path} holds no *.yaml map files")
            out.extend(found)
        elif path.is_file():
            out.append(str(path))
        else:
            raise FileNotFoundError(
                f"maps entry {item!r} is neither an existing folder or yaml file nor a generator spec "
                f"kind:seed with kind in {sorted(GENERATORS)}"
            )
    if len(set(out)) != len(out):
        dup = [k for k, v in Counter(out).items() if v > 1]
        raise ValueError(f"maps= names the same map more than once: {dup}")
    return out


def _real_ids(paths: Iterable[str]) -> dict[str, str]:
    """Yaml stem as id; parent folder prefixed where stems collide."""
    paths = list(paths)
    stems = Counter(Path(p).stem for p in paths)
    return {p: (Path(p).stem if stems[Path(p).stem] == 1 else f"{Path(p).parent.name}-{Path(p).stem}")
            for p in paths}


def load_map_sources(maps: Any, resolution: float) -> list[MapSource]:
    """Load every map of ``maps`` at ``resolution`` metres per pixel (real maps are resampled if needed)."""
    specs = expand_map_specs(maps)
    real_ids = _real_ids([s for s in specs if parse_procedural(s) is None])
    out = []
    for spec in specs:
        proc = parse_procedural(spec)
        if proc is not None:
            m = generate_map(proc[0], proc[1], resolution=resolution)
            map_id = procedural_id(*proc)
        else:
            m = load_ros_map(spec)
            map_id = real_ids[spec]
        if abs(m.resolution - resolution) > 1e-9:
            m = m.resampled(resolution)
        out.append(MapSource(map_id, spec, m))
    ids = Counter(s.map_id for s in out)
    if any(v > 1 for v in ids.values()):
        raise ValueError(f"two maps share an id: {[k for k, v in ids.items() if v > 1]}; rename one yaml")
    return out
