"""Plan with a trained student: a map (or a local window), a robot position and a goal in, waypoints out.

The student only ever saw the windows of the annotation tool (:mod:`spade.annotation.rasterize`), so a query is
turned into exactly such a window:

- the map is resampled to the student's resolution (``OccupancyMap.resampled``: obstacles never vanish);
- the window is axis-aligned with the map (as Nav2's rolling local costmap and the annotation tool's windows),
  its top-left cell an integer cell of that map and cells outside the map unknown (``rasterize.crop``). The
  annotation tool draws the window uniformly among the placements that keep the whole remaining path
  ``margin_m`` inside it; a planner knows only the start and the goal, so it takes the middle of the placements
  that keep those two ``margin_m`` inside, i.e. centres the window on them. A map that already is a window of
  the student's size and resolution (a local costmap) is used as it is;
- the goal must lie in the window, as in every training instance. A goal too far for one window is a failure
  (``far_goal="fail"``) or, with ``far_goal="clip"``, replaced by the farthest free point towards it that fits
  (a sub-goal: plan again from nearer the goal);
- the state is the dataset's encoding (``spade.data.PathDataset``): occupancy ``code * 0.5``, then the start
  and goal discs drawn by ``rasterize.render`` (radius ``disc_radius_m``).

The path is extracted with :func:`spade.metrics.extract_path` (the evaluation's extraction) and converted back
to map-frame metres. Every way a query can fail gives a :class:`PlanResult` with ``success=False``, a short
``code`` and a readable ``reason``, keeping whatever was computed (window, probabilities) for debugging.

Backends: a Lightning checkpoint written by ``python -m spade.train`` (PyTorch) or an ONNX file written by
``spade.deploy.export`` (onnxruntime); both give the same probabilities for the same window.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Union

import numpy as np

from spade.annotation.rasterize import crop, render
from spade.maps import FREE, OCCUPIED, OccupancyMap, load_ros_map
from spade.metrics import ExtractedPath, extract_path

__all__ = ["PlanResult", "Planner", "PlannerConfigError", "WindowPlacement"]

MapLike = Union[OccupancyMap, str, Path]

# The annotation tool's defaults (conf/annotate.yaml): what a checkpoint that does not record them was trained on.
DEFAULT_DISC_RADIUS_M = 0.1
DEFAULT_MARGIN_M = 0.3


class PlannerConfigError(ValueError):
    """A model file the planner cannot use as it is (wrong role, missing window description, bad option)."""


@dataclass(frozen=True)
class WindowPlacement:
    """The student's window in a map at the student's resolution: top-left cell (col0, row0), (height, width)."""

    map: OccupancyMap
    col0: int
    row0: int
    height: int
    width: int

    @property
    def offset(self) -> np.ndarray:
        return np.array([self.col0, self.row0], dtype=np.float64)

    def to_window(self, xy_m: np.ndarray) -> np.ndarray:
        """Map-frame metres (..., 2) -> window pixel coordinates (..., 2) (x = column, y = row)."""
        return self.map.world_to_pixel(np.asarray(xy_m, dtype=np.float64)) - self.offset

    def to_world(self, px: np.ndarray) -> np.ndarray:
        """Window pixel coordinates (..., 2) -> map-frame metres (..., 2)."""
        return self.map.pixel_to_world(np.asarray(px, dtype=np.float64) + self.offset)

    def occupancy(self) -> np.ndarray:
        """(H, W) uint8 codes of the window; cells outside the map are unknown (as in the training windows)."""
        if (self.height, self.width) == self.map.grid.shape and self.col0 == 0 and self.row0 == 0:
            return self.map.grid
        if self.height == self.width:
            return crop(self.map.grid, self.col0, self.row0, self.height)
        out = crop(self.map.grid, self.col0, self.row0, max(self.height, self.width))
        return np.ascontiguousarray(out[: self.height, : self.width])

    @property
    def bounds_m(self) -> tuple[float, float, float, float]:
        """(x_min, y_min, x_max, y_max) of the window's outer edges in map-frame metres."""
        corners = self.to_world(np.array([[-0.5, self.height - 0.5], [self.width - 0.5, -0.5]]))
        return float(corners[0, 0]), float(corners[0, 1]), float(corners[1, 0]), float(corners[1, 1])


@dataclass
class PlanResult:
    """The outcome of one query.

    ``waypoints``: (K, 2) float64 map-frame metres from the start to the goal, evenly spaced by arc length; an
    empty (0, 2) array when ``success`` is False. ``code``: None on success, else one of ``start_outside_map``,
    ``start_not_free``, ``goal_outside_map``, ``goal_not_free``, ``goal_too_far``, ``empty`` (no pixel above the
    threshold), ``too_short``, ``goal_not_reached``, ``collision``; ``reason`` says it in words. ``goal``: the
    goal planned to (the sub-goal when ``far_goal="clip"`` moved it; then ``subgoal`` is True). ``probability``:
    the (H, W) path probabilities of the window and ``state`` the (3, H, W) network input (None when the query
    failed before the network ran); ``pixels``: the waypoints in window pixel coordinates; ``extraction``: the
    raw :class:`~spade.metrics.ExtractedPath`; ``blocked``: waypoints and path pixels on non-free cells.
    """

    success: bool
    waypoints: np.ndarray
    code: str | None = None
    reason: str | None = None
    start: np.ndarray | None = None
    goal: np.ndarray | None = None
    subgoal: bool = False
    window: WindowPlacement | None = None
    state: np.ndarray | None = field(default=None, repr=False)
    probability: np.ndarray | None = field(default=None, repr=False)
    pixels: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)), repr=False)
    extraction: ExtractedPath | None = field(default=None, repr=False)
    blocked: int = 0

    def __bool__(self) -> bool:
        return self.success

    @property
    def length_m(self) -> float:
        """Length of the waypoint polyline in metres (0 on failure)."""
        if len(self.waypoints) < 2:
            return 0.0
        return float(np.linalg.norm(np.diff(self.waypoints, axis=0), axis=1).sum())


def _failure(code: str, reason: str, **kwargs: Any) -> PlanResult:
    return PlanResult(success=False, waypoints=np.zeros((0, 2)), code=code, reason=reason, **kwargs)


def _point(value: Any, name: str) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64).reshape(-1)
    if arr.shape not in ((2,), (3,)) or not np.isfinite(arr).all():
        raise ValueError(f"{name} must be (x, y) or a pose (x, y, yaw) in map-frame metres, got {value!r}")
    return arr[:2].copy()


def _sigmoid(x: np.ndarray) -> np.ndarray:
    return (0.5 * (1.0 + np.tanh(0.5 * x))).astype(np.float32)


class _TorchBackend:
    """A student's network from a Lightning checkpoint (no LightningModule, no expert needed)."""

    def __init__(self, path: Path, device: str) -> None:
        import torch

        from spade.models import model_from_config

        checkpoint = torch.load(path, map_location="cpu", weights_only=False)
        info = checkpoint.get("spade") if isinstance(checkpoint, dict) else None
        if not info:
            raise PlannerConfigError(f"{path} is not a SPADE checkpoint (no 'spade' entry); pass a student "
                                     "checkpoint written by python -m spade.train or its ONNX export")
        if info.get("role") != "student":
            raise PlannerConfigError(f"{path} is a {info.get('role')!r} checkpoint; the planner runs students only "
                                     "(experts are for training)")
        self.info = info
        self.net = model_from_config(dict(info["config"]))
        weights = {k[len("net."):]: v for k, v in checkpoint["state_dict"].items() if k.startswith("net.")}
        self.net.load_state_dict(weights)
        self.device = torch.device(device)
        self.net.to(self.device).eval()

    def logits(self, states: np.ndarray) -> np.ndarray:
        import torch

        with torch.inference_mode():
            x = torch.from_numpy(np.ascontiguousarray(states, dtype=np.float32)).to(self.device)
            return self.net(x).float().cpu().numpy()


class _OnnxBackend:
    """An exported student run by onnxruntime: input ``state`` (N, 3, H, W), output ``logits`` (N, 1, H, W)."""

    def __init__(self, path: Path, device: str) -> None:
        try:
            import onnxruntime as ort
        except ImportError:  # pragma: no cover - depends on the installed extras
            raise ImportError("planning with an .onnx file needs onnxruntime: pip install -e '.[onnx]'") from None
        providers = ["CPUExecutionProvider"]
        if device.startswith("cuda"):
            providers.insert(0, "CUDAExecutionProvider")
        self.session = ort.InferenceSession(str(path), providers=providers)
        meta = self.session.get_modelmeta().custom_metadata_map
        if "spade" not in meta:
            raise PlannerConfigError(f"{path} carries no 'spade' metadata; export students with "
                                     "spade.deploy.export.export_student (python -m spade.export)")
        self.info = json.loads(meta["spade"])
        if self.info.get("role") != "student":
            raise PlannerConfigError(f"{path} holds a {self.info.get('role')!r} model; the planner runs students only")
        self.input = self.session.get_inputs()[0].name
        outputs = [o.name for o in self.session.get_outputs()]
        self.output = "logits" if "logits" in outputs else outputs[0]

    def logits(self, states: np.ndarray) -> np.ndarray:
        x = np.ascontiguousarray(states, dtype=np.float32)
        return np.asarray(self.session.run([self.output], {self.input: x})[0], dtype=np.float32)


class Planner:
    """A trained student as a path planner (see the module docstring for how queries become windows).

    Args:
        model: a student checkpoint (``.ckpt``, from ``python -m spade.train``) or its ONNX export (``.onnx``).
        device: ``cpu`` or ``cuda[:N]`` (PyTorch device; for ONNX, ``cuda`` asks for the CUDA provider first).
        image_size, resolution_m: the student's window (H, W) / (S, S) and metres per pixel. Read from the model
            file (``checkpoint["spade"]["data"]``, written by every fit since the planner exists); give them only
            for older checkpoints, and then exactly as the student was trained (the scale's image_size and
            resolution_m).
        num_waypoints: points of the returned polyline.
        threshold, max_gap, goal_tolerance_px: :func:`spade.metrics.extract_path` options (the evaluation's).
        disc_radius_m, margin_m: the annotation tool's ``instances.disc_radius_m`` and ``window.margin_m`` the
            student was trained with (defaults: conf/annotate.yaml's, unless the model file records them).
        far_goal: ``fail`` (default) or ``clip`` (plan to the farthest free point towards the goal that fits).
        require_goal: a path that does not reach the goal (within ``goal_tolerance_px``) is a failure.
        collision_check: a path over a non-free cell of the window (occupied or unknown) is a failure.
        batch_size: windows per forward pass in :meth:`plan_batch`.
    """

    def __init__(
        self,
        model: str | Path,
        *,
        device: str = "cpu",
        image_size: int | Sequence[int] | None = None,
        resolution_m: float | None = None,
        num_waypoints: int = 64,
        threshold: float = 0.5,
        max_gap: float = 2.0,
        goal_tolerance_px: float = 4.0,
        disc_radius_m: float | None = None,
        margin_m: float | None = None,
        far_goal: str = "fail",
        require_goal: bool = True,
        collision_check: bool = True,
        batch_size: int = 64,
    ) -> None:
        path = Path(model).expanduser()
        if not path.is_file():
            raise FileNotFoundError(f"planner model {path} does not exist; pass a student checkpoint (.ckpt) from "
                                    "python -m spade.train or its ONNX export (.onnx)")
        self.path = path
        self.backend = _OnnxBackend(path, device) if path.suffix == ".onnx" else _TorchBackend(path, device)
        data = dict(self.backend.info.get("data") or {})
        self.image_size = self._image_size(image_size if image_size is not None else data.get("image_size"))
        res = resolution_m if resolution_m is not None else data.get("resolution_m")
        if res is None:
            raise PlannerConfigError(
                f"{path} does not record the window it was trained on (no 'data' entry: written before fits stored "
                "it). Pass image_size= and resolution_m= exactly as the student was trained (its scale's "
                "image_size and resolution_m, e.g. 64 and 0.1 for scale=tiny), or retrain/re-export it"
            )
        self.resolution = float(res)
        if not (math.isfinite(self.resolution) and self.resolution > 0):
            raise PlannerConfigError(f"resolution_m must be a positive number of metres per pixel, got {res!r}")
        self.disc_radius_m = float(disc_radius_m if disc_radius_m is not None
                                   else data.get("disc_radius_m", DEFAULT_DISC_RADIUS_M))
        self.margin_m = float(margin_m if margin_m is not None else data.get("margin_m", DEFAULT_MARGIN_M))
        if num_waypoints < 2:
            raise PlannerConfigError(f"num_waypoints must be >= 2, got {num_waypoints}")
        if far_goal not in ("fail", "clip"):
            raise PlannerConfigError(f"far_goal must be 'fail' or 'clip', got {far_goal!r}")
        if batch_size < 1:
            raise PlannerConfigError(f"batch_size must be >= 1, got {batch_size}")
        self.num_waypoints, self.threshold, self.max_gap = int(num_waypoints), float(threshold), float(max_gap)
        self.goal_tolerance_px = float(goal_tolerance_px)
        self.far_goal, self.require_goal, self.collision_check = far_goal, bool(require_goal), bool(collision_check)
        self.batch_size = int(batch_size)
        self._cache: tuple[OccupancyMap, OccupancyMap] | None = None  # (map given, map at the student's resolution)

    @staticmethod
    def _image_size(value: Any) -> tuple[int, int] | None:
        if value is None:
            raise PlannerConfigError(
                "the model file does not record its window size (no 'data' entry); pass image_size= (and "
                "resolution_m=) exactly as the student was trained"
            )
        size = [int(v) for v in (value if isinstance(value, (list, tuple)) else [value, value])]
        if len(size) != 2 or min(size) < 8:
            raise PlannerConfigError(f"image_size must be S or (H, W) with sides >= 8, got {value!r}")
        return size[0], size[1]

    def __repr__(self) -> str:
        h, w = self.image_size
        return f"Planner({self.path.name}, {h}x{w} px at {self.resolution} m/px)"

    # -- network ---------------------------------------------------------------------------------------------
    def predict(self, states: np.ndarray) -> np.ndarray:
        """Path probabilities (N, H, W) of network inputs (N, 3, H, W), in chunks of ``batch_size``."""
        states = np.asarray(states, dtype=np.float32)
        if states.ndim != 4 or states.shape[1] != 3 or tuple(states.shape[2:]) != self.image_size:
            raise ValueError(f"states must be (N, 3, {self.image_size[0]}, {self.image_size[1]}), got {states.shape}")
        out = [self.backend.logits(states[i: i + self.batch_size]) for i in range(0, len(states), self.batch_size)]
        return _sigmoid(np.concatenate(out)[:, 0]) if out else np.zeros((0, *self.image_size), np.float32)

    # -- queries ---------------------------------------------------------------------------------------------
    def plan(self, map: MapLike, start: Any, goal: Any) -> PlanResult:
        """Plan from ``start`` (x, y[, yaw]) to ``goal`` (x, y) in map-frame metres on ``map``.

        ``map``: an :class:`OccupancyMap` (a whole map, or a local window such as a rolling costmap converted to
        codes, with its origin in the map frame) or the path of a ROS map yaml.
        """
        return self.plan_batch(map, [start], [goal])[0]

    def plan_batch(self, maps: MapLike | Sequence[MapLike], starts: Any, goals: Any) -> list[PlanResult]:
        """:meth:`plan` for N queries in one pass of the network: ``maps`` one map for all or one per query,
        ``starts`` (N, 2|3) and ``goals`` (N, 2) in map-frame metres."""
        starts = [_point(s, "start") for s in starts]
        goals = [_point(g, "goal") for g in goals]
        if len(starts) != len(goals):
            raise ValueError(f"plan_batch got {len(starts)} starts and {len(goals)} goals; give one goal per start")
        if isinstance(maps, (OccupancyMap, str, Path)):
            maps = [maps] * len(starts)
        maps = list(maps)
        if len(maps) != len(starts):
            raise ValueError(f"plan_batch got {len(maps)} maps for {len(starts)} queries; give one map or one each")
        loaded: dict[int, OccupancyMap] = {}
        results: list[PlanResult | None] = []
        pending: list[tuple[int, WindowPlacement, np.ndarray, np.ndarray, np.ndarray, bool]] = []
        for i, (m, s, g) in enumerate(zip(maps, starts, goals)):
            key = id(m)
            if key not in loaded:
                loaded[key] = m if isinstance(m, OccupancyMap) else load_ros_map(m)
            prepared = self._prepare(loaded[key], s, g)
            if isinstance(prepared, PlanResult):
                results.append(prepared)
                continue
            window, start_px, goal_px, goal_m, subgoal = prepared
            results.append(None)
            pending.append((i, window, start_px, goal_px, goal_m, subgoal))
        if pending:
            states = np.stack([self.encode(w.occupancy(), s, g) for _, w, s, g, _, _ in pending])
            probs = self.predict(states)
            for (i, window, start_px, goal_px, goal_m, subgoal), state, prob in zip(pending, states, probs):
                results[i] = self._extract(window, state, prob, starts[i], start_px, goal_px, goal_m, subgoal)
        return results  # type: ignore[return-value]

    # -- steps -----------------------------------------------------------------------------------------------
    def encode(self, occupancy: np.ndarray, start_px: np.ndarray, goal_px: np.ndarray) -> np.ndarray:
        """The (3, H, W) float32 network input of a window: occupancy code * 0.5, start disc, goal disc."""
        occupancy = np.asarray(occupancy, dtype=np.uint8)
        h, w = occupancy.shape
        side = max(h, w)
        square = crop(occupancy, 0, 0, side) if h != w else occupancy
        # The annotation tool's own rasteriser draws the discs, so they are the training discs pixel for pixel.
        inst = render(square, np.stack([start_px, goal_px]), self.disc_radius_m / self.resolution, 2)
        state = np.empty((3, h, w), dtype=np.float32)
        np.multiply(occupancy, np.float32(0.5), out=state[0])
        state[1] = inst.start[:h, :w]
        state[2] = inst.goal[:h, :w]
        return state

    def _at_resolution(self, m: OccupancyMap) -> OccupancyMap:
        if abs(m.resolution - self.resolution) <= 1e-9 * self.resolution:
            return m
        if self._cache is not None and self._cache[0] is m:
            return self._cache[1]
        resampled = m.resampled(self.resolution)
        self._cache = (m, resampled)
        return resampled

    def _check_endpoint(self, m: OccupancyMap, xy: np.ndarray, name: str) -> PlanResult | None:
        col, row = np.rint(m.world_to_pixel(xy)).astype(np.int64)
        if not (0 <= row < m.height and 0 <= col < m.width):
            x0, y0 = m.origin[0], m.origin[1]
            wm, hm = m.size_m
            return _failure(f"{name}_outside_map", f"{name} ({xy[0]:.2f}, {xy[1]:.2f}) m lies outside map {m.name!r}, "
                            f"which spans x {x0:.2f}..{x0 + wm:.2f} m, y {y0:.2f}..{y0 + hm:.2f} m")
        code = int(m.grid[row, col])
        if code != FREE:
            what = "an obstacle" if code == OCCUPIED else "unknown space"
            return _failure(f"{name}_not_free", f"{name} ({xy[0]:.2f}, {xy[1]:.2f}) m lies in {what} (cell col {col}, "
                            f"row {row} of map {m.name!r}); give a {name} on a free cell")
        return None

    def _prepare(self, given: OccupancyMap, start: np.ndarray, goal: np.ndarray
                 ) -> PlanResult | tuple[WindowPlacement, np.ndarray, np.ndarray, np.ndarray, bool]:
        for xy, name in ((start, "start"), (goal, "goal")):
            failed = self._check_endpoint(given, xy, name)
            if failed is not None:
                failed.start, failed.goal = start, goal
                return failed
        m = self._at_resolution(given)
        h, w = self.image_size
        start_map = m.world_to_pixel(start)
        goal_map = m.world_to_pixel(goal)
        if m.grid.shape == (h, w):  # already a window of the student's: use it as it is
            return WindowPlacement(m, 0, 0, h, w), start_map, goal_map, goal, False
        placement = self._place(m, start_map, goal_map)
        subgoal = False
        if placement is None and self.far_goal == "clip":
            clipped = self._clip_goal(m, start_map, goal_map)
            if clipped is not None:
                goal_map, subgoal = clipped, True
                placement = self._place(m, start_map, goal_map)
        if placement is None:
            span = np.abs(goal_map - start_map) * self.resolution
            return _failure(
                "goal_too_far",
                f"goal is {span[0]:.2f} m x {span[1]:.2f} m from the start; the student's window covers "
                f"{w * self.resolution:.2f} m x {h * self.resolution:.2f} m with start and goal {self.margin_m} m "
                "inside it. Give a nearer goal (a waypoint of a global plan) or use far_goal='clip'",
                start=start, goal=goal,
            )
        offset = np.array([placement.col0, placement.row0], dtype=np.float64)
        return placement, start_map - offset, goal_map - offset, m.pixel_to_world(goal_map), subgoal

    def _bounds(self, lo_pts: np.ndarray, hi_pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Integer top-left cells keeping the points ``margin_m`` inside (``rasterize.place_window``'s range)."""
        h, w = self.image_size
        size = np.array([w, h], dtype=np.float64)
        margin = self.margin_m / self.resolution
        lo = np.ceil(hi_pts + margin - (size - 1) - 1e-9).astype(np.int64)
        hi = np.floor(lo_pts - margin + 1e-9).astype(np.int64)
        return lo, hi

    def _place(self, m: OccupancyMap, start_px: np.ndarray, goal_px: np.ndarray) -> WindowPlacement | None:
        pts = np.stack([start_px, goal_px])
        lo, hi = self._bounds(pts.min(axis=0), pts.max(axis=0))
        if (lo > hi).any():
            return None
        col0, row0 = (np.floor((lo + hi) / 2.0 + 0.5)).astype(np.int64)  # the middle of the allowed placements
        h, w = self.image_size
        return WindowPlacement(m, int(col0), int(row0), h, w)

    def _clip_goal(self, m: OccupancyMap, start_px: np.ndarray, goal_px: np.ndarray) -> np.ndarray | None:
        """The farthest free cell on the segment start -> goal that still fits in one window with the start."""
        h, w = self.image_size
        reach = np.array([w, h], dtype=np.float64) - 1 - 2 * self.margin_m / self.resolution - 1.0
        direction = goal_px - start_px
        length = float(np.linalg.norm(direction))
        if length == 0 or (reach <= 0).any():
            return None
        unit = direction / length
        with np.errstate(divide="ignore"):
            limit = float(np.min(np.where(np.abs(unit) > 1e-12, reach / np.abs(unit), np.inf)))
        min_dist = 2.0 * self.margin_m / self.resolution
        for dist in np.arange(min(limit, length), min_dist, -0.5):
            cand = start_px + unit * dist
            col, row = np.rint(cand).astype(np.int64)
            if 0 <= row < m.height and 0 <= col < m.width and m.grid[row, col] == FREE:
                return cand
        return None

    def _extract(self, window: WindowPlacement, state: np.ndarray, prob: np.ndarray, start_m: np.ndarray,
                 start_px: np.ndarray, goal_px: np.ndarray, goal_m: np.ndarray, subgoal: bool) -> PlanResult:
        found = extract_path(prob, start_px, goal_px, self.num_waypoints, threshold=self.threshold,
                             max_gap=self.max_gap, goal_tolerance=self.goal_tolerance_px)
        common = dict(start=start_m, goal=np.asarray(goal_m, dtype=np.float64), subgoal=subgoal, window=window,
                      state=state, probability=prob, extraction=found)
        if not found.ok:
            why = {"empty": f"no pixel of the predicted path reaches probability {self.threshold}",
                   "too_short": "the predicted path near the start is a single pixel"}.get(found.failure, found.failure)
            return _failure(found.failure or "empty", f"no path extracted: {why}", **common)
        if self.require_goal and not found.reached_goal:
            end = found.pixels[-1]
            gap = float(np.linalg.norm(end - goal_px)) * self.resolution
            return _failure("goal_not_reached", f"the predicted path stops {gap:.2f} m from the goal", **common)
        occupancy = state[0]
        cells = np.vstack([found.pixels, found.points])
        cols = np.clip(np.rint(cells[:, 0]).astype(np.int64), 0, occupancy.shape[1] - 1)
        rows = np.clip(np.rint(cells[:, 1]).astype(np.int64), 0, occupancy.shape[0] - 1)
        blocked = int((occupancy[rows, cols] != np.float32(FREE * 0.5)).sum())
        if self.collision_check and blocked:
            return _failure("collision", f"the predicted path crosses {blocked} non-free cells", blocked=blocked,
                            **common)
        return PlanResult(success=True, waypoints=window.to_world(found.points), pixels=found.points,
                          blocked=blocked, **common)
