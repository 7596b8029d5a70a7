"""One map, a training set and a test set that share nothing: ``split=area:PART`` or ``split=scenario:PART``.

``split=area:train`` / ``split=area:test`` cut the map's free area by a line across one axis (``split_axis``: x, y,
or auto, the longer side of the free area) where ``split_fraction`` of the free cells (default 0.7) lie on the low
side (smaller map x or y, in metres). The training part is that side, the test part the other; a scenario's goal is
drawn on its part's side and a scenario whose sketch or executed path (from start to goal) does not lie wholly on
that side is rejected (``split_crossing`` in the manifest's rejections). Windows near the line still *see* the
other side's map, as a robot there would.

``split=scenario:train`` / ``split=scenario:test`` divide one seed's sequence of scenarios by index: scenario ``k``
belongs to the training part when ``blake2b("spade-split/k")`` read as a fraction of 2**64 is below
``split_fraction``, to the test part otherwise. With the same seed the two sets never hold the same scenario, but
their goals are drawn over the same areas of the map.

The split is part of the settings that shape a dataset's bytes (the manifest's ``generator`` records ``split``,
``split_fraction`` and ``split_axis``); the manifest's ``extra.split`` records it resolved (the line of each map).
Two datasets are a training and a test part of one split when those records agree but for the part
(:func:`split_pair_problems`). A preset's own ``split: train|test`` (``preset=transfer``, which splits by
``scenario.areas`` and ``scenario.first_index``) is left to the preset.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from spade.data.checks import split_pair_problems  # noqa: F401  (the data checks own it; kept importable here)
from spade.maps.occupancy import FREE
from spade.utils.errors import ConfigError
from spade.data.format import read_manifest_json

MODES = ("area", "scenario")
PARTS = ("train", "test")
AXES = ("x", "y", "auto")
DEFAULT_FRACTION = 0.7
CROSSING = "split_crossing"  # the rejection counter of a scenario that does not stay on its part's side
_FIX = "use split=area:train / split=area:test (by area) or split=scenario:train / split=scenario:test (by scenario)"


class SplitError(ConfigError):
    """A ``split`` setting that cannot be applied (one line: the key, the value and the fix)."""


@dataclass(frozen=True)
class Split:
    """A resolved ``split``: ``mode`` area or scenario, ``part`` train or test, the training ``fraction`` and, for
    an area split, the ``axis`` (x, y or auto)."""

    mode: str
    part: str
    fraction: float
    axis: str

    def settings(self) -> dict[str, Any]:
        out: dict[str, Any] = {"mode": self.mode, "part": self.part, "fraction": self.fraction}
        if self.mode == "area":
            out["axis"] = self.axis
        else:
            out["rule"] = ("scenario index k is in the training part when blake2b('spade-split/k') / 2**64 < "
                           "fraction, in the test part otherwise")
        return out


def _number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and np.isfinite(value)


def parse_split(cfg: Mapping[str, Any]) -> Split | None:
    """The ``split`` of an annotation config (None when unset, or a preset's own ``split: train|test``).

    Raises :class:`SplitError` for an unknown mode or part, ``split_fraction`` outside (0, 1), an unknown
    ``split_axis``, split settings without ``split``, and a split of sources that are not drawn on ``maps=``.
    """
    value = cfg.get("split")
    fraction = cfg.get("split_fraction")
    axis = cfg.get("split_axis")
    preset_split = value in PARTS and cfg.get("transfer_splits") is not None
    if value in (None, "") or preset_split:
        for key, given in (("split_fraction", fraction), ("split_axis", axis)):
            if given is not None:
                raise SplitError(f"{key}={given} has no effect without an area or scenario split; {_FIX}, or "
                                 f"remove {key}")
        return None
    mode, sep, part = str(value).partition(":")
    if not sep or mode not in MODES:
        preset = " (split=train or split=test alone is preset=transfer's own)" if value in PARTS else ""
        raise SplitError(f"split={value} is not a split of one map; {_FIX}{preset}")
    if part not in PARTS:
        raise SplitError(f"split={value}: the part after '{mode}:' must be train or test; use split={mode}:train "
                         f"for the training set and split={mode}:test for the test set")
    if fraction is None:
        fraction = DEFAULT_FRACTION
    if not _number(fraction) or not 0.0 < float(fraction) < 1.0:
        raise SplitError(f"split_fraction={fraction} must be a number strictly between 0 and 1 (the training "
                         f"part's share); e.g. split_fraction={DEFAULT_FRACTION}")
    if mode == "scenario" and axis is not None:
        raise SplitError(f"split_axis={axis} applies to split=area:{part} only; remove split_axis for split={value}")
    axis = "auto" if axis is None else str(axis)
    if axis not in AXES:
        raise SplitError(f"split_axis={axis} is not one of x, y, auto; e.g. split_axis=auto (the longer side of the "
                         "map's free area)")
    for key in ("sketches", "rosbag.paths", "skipp.root"):
        section, _, leaf = key.partition(".")
        given = (cfg.get(section) or {}).get(leaf) if leaf else cfg.get(section)
        if given not in (None, "", []):
            raise SplitError(f"split={value} splits the scenarios drawn on maps=, but {key}={given} is not drawn; "
                             "remove split= (split the sketches or recordings into two files instead)")
    return Split(mode, part, float(fraction), axis)


# ------------------------------------------------------------------------------------------------ by scenario
def scenario_share(index: int) -> float:
    """Scenario ``index``'s place in [0, 1): the training part holds it when this is below the fraction."""
    digest = hashlib.blake2b(f"spade-split/{int(index)}".encode(), digest_size=8).digest()
    return int.from_bytes(digest, "big") / 2.0**64


def in_scenario_part(split: Split, index: int) -> bool:
    """Whether scenario ``index`` belongs to ``split``'s part (the training and test parts are complements)."""
    return (scenario_share(index) < split.fraction) == (split.part == "train")


# ---------------------------------------------------------------------------------------------------- by area
@dataclass(frozen=True)
class AreaLine:
    """The line that splits one map, and the side of it that a part's scenarios keep to.

    The line lies across ``axis`` (world x or y) at ``boundary`` on the key coordinate of a map pixel point
    (x, y): ``x`` for axis x, ``height - 1 - y`` for axis y (world y grows up, image rows down), so the training
    part is the low side in world metres (``key < boundary``) and the test part the high side (``key >
    boundary``); a point on the line belongs to neither.
    """

    map_id: str
    axis: str
    boundary: float
    height: int
    part: str
    at_m: float  # the line in map metres (world x or y)
    train_share: float  # the share of the map's free cells on the training side
    map_sha256: str  # the map's grid at the window resolution, so that both parts can be checked to share it

    def key(self, points: np.ndarray) -> np.ndarray:
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        return pts[:, 0] if self.axis == "x" else (self.height - 1) - pts[:, 1]

    def on_side(self, points: np.ndarray) -> np.ndarray:
        """Per point (map pixels, (N, 2) x/y): whether it lies strictly on this part's side of the line."""
        key = self.key(points)
        return key < self.boundary if self.part == "train" else key > self.boundary

    def holds(self, points: np.ndarray) -> bool:
        """Whether every point lies on this part's side."""
        return bool(self.on_side(points).all())

    def to_json(self) -> dict[str, Any]:
        side = "<" if self.part == "train" else ">"
        return {"axis": self.axis, "at_m": round(self.at_m, 6), "train_share": round(self.train_share, 4),
                "part_side": f"{self.axis} {side} {self.at_m:.3f} m", "map_sha256": self.map_sha256}


def grid_digest(grid: np.ndarray, resolution: float) -> str:
    """The sha256 of a map's grid (its shape, resolution and cells)."""
    h = hashlib.sha256(f"{grid.shape[0]}x{grid.shape[1]}@{resolution!r}:".encode())
    h.update(np.ascontiguousarray(grid, dtype=np.uint8).tobytes())
    return h.hexdigest()


def area_line(map_id: str, grid: np.ndarray, resolution: float, origin: tuple[float, float, float],
              split: Split) -> AreaLine:
    """The line across ``split.axis`` with ``split.fraction`` of the map's free cells on its low side (between
    two rows or columns of cells, the share nearest the fraction with free cells on both sides)."""
    rows, cols = np.nonzero(grid == FREE)
    height, width = grid.shape
    if len(rows) < 2:
        raise SplitError(f"split={split.mode}:{split.part}: map {map_id!r} has {len(rows)} free cells, too few to "
                         "split; remove split= or choose another map")
    axis = split.axis
    if axis == "auto":
        axis = "x" if cols.max() - cols.min() >= rows.max() - rows.min() else "y"
    key = cols if axis == "x" else (height - 1) - rows
    n = width if axis == "x" else height
    below = np.concatenate([[0], np.cumsum(np.bincount(key, minlength=n))])  # below[c]: free cells with key < c
    total = int(below[-1])
    candidates = np.flatnonzero((below > 0) & (below < total))
    if len(candidates) == 0:
        raise SplitError(f"split={split.mode}:{split.part}: the free cells of map {map_id!r} lie in one "
                         f"{'column' if axis == 'x' else 'row'}; use split_axis={'y' if axis == 'x' else 'x'}")
    c = int(candidates[np.argmin(np.abs(below[candidates] / total - split.fraction))])
    at_m = float(origin[0] if axis == "x" else origin[1]) + c * resolution
    return AreaLine(map_id, axis, c - 0.5, height, split.part, at_m, float(below[c]) / total,
                    grid_digest(grid, resolution))


# ------------------------------------------------------------------------------------------------ the records
def split_record(split: Split | None, lines: list[AreaLine | None] | None = None) -> dict[str, Any] | None:
    """What a manifest's ``extra.split`` records: the resolved settings and, for an area split, each map's line."""
    if split is None:
        return None
    out = split.settings()
    if split.mode == "area":
        out["lines"] = {line.map_id: line.to_json() for line in lines or [] if line is not None}
    return out


def read_split(root: str | Path) -> dict[str, Any] | None:
    """The ``extra.split`` record of a dataset's manifest (None for a dataset made without a split)."""
    record = (read_manifest_json(root).get("extra") or {}).get("split")
    return dict(record) if isinstance(record, dict) else None


