"""What the sketching app does, independent of HTTP: one map, its costmap, the sketch file, dataset builds and
the planner.

Nothing here reimplements the annotation tool. The map is loaded as ``python -m spade.annotate sketches=``
loads a sketch file's map (``load_map_sources`` at ``window.resolution_m``), its costmap is the annotation
tool's (``costmap_context`` -> ``build_costmap``), a sketch is executed and checked by
:func:`spade.annotation.pipeline.execute_operator_sketch` (the function ``sketch_instances`` applies to every
sketch of a file), the dataset is built by :func:`spade.annotate.annotate` with ``sketches=`` and the policy is
:class:`spade.deploy.student_planner.Planner`.
"""

from __future__ import annotations

import base64
import io
import logging
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
from PIL import Image
from scipy.spatial import cKDTree

from spade.annotation.execution import Rejection
from spade.annotation.pipeline import WindowFitRule, execute_operator_sketch, sketch_window_fit
from spade.annotation.scenarios import costmap_context
from spade.annotation.sketch_file import Sketch, SketchFileError, densify, sketch_to_pixels
from spade.annotation.sources import load_map_sources, parse_procedural
from spade.annotation.templates import SHAPES, check_shape
from spade.maps import FREE, OCCUPIED
from spade.sketching.storage import SketchStore, StorageError
from spade.utils import palette
from spade.utils.errors import ConfigError
from spade.utils.provenance import shown_path
from spade.annotation.run import alias_preset, annotate
from spade.utils.config import compose_config

log = logging.getLogger(__name__)

MODEL_SUFFIXES = (".ckpt", ".onnx", ".pt")  # what load_model opens: model files only

# Words for the rejection reasons of the annotation tool (the keys counted in a dataset's manifest).
REASONS = {
    "sketch_off_map": "a waypoint lies outside the map",
    "sketch_off_free": "a waypoint lies on an obstacle, on unknown space or closer to an obstacle than the "
                       "robot radius (the red band of the costmap overlay)",
    "no_path": "the robot cannot drive between two consecutive waypoints without touching an obstacle",
    "non_free": "the executed path runs off the free space (closer to an obstacle than the robot radius)",
    "deviation": "the executed path strays too far from the sketch (an obstacle or a too tight corner in the way)",
    "shape": "the executed path does not turn like the shape: an L turns 90 degrees, a U 180 degrees",
    "window": "the sketch does not fit the student's window drawn from its first waypoint (sketch a shorter "
              "manoeuvre, or start it closer to the turn)",
}


class RequestError(ValueError):
    """A request the app refuses; ``status`` is the HTTP status to answer with (4xx)."""

    def __init__(self, message: str, status: int = 422) -> None:
        super().__init__(message)
        self.status = status


def annotation_config(overrides: Sequence[str] = ()) -> dict[str, Any]:
    """conf/annotate.yaml composed with ``overrides`` (``key=value`` as on spade.annotate's command line,
    ``preset=NAME`` included), as a plain dict."""
    from omegaconf import OmegaConf

    cfg = compose_config("annotate", alias_preset(list(overrides)))  # inside spade.sketch's Hydra app too
    out: dict[str, Any] = OmegaConf.to_container(cfg, resolve=True)  # type: ignore[assignment]
    out.pop("hydra", None)
    return out


def _confidence(result: Any) -> dict[str, Any] | None:
    """A plan's confidence for the page: share of its length through p < 0.5, lowest p, the flags (search only)."""
    share = getattr(result, "low_share", float("nan"))
    if not result.success or share is None or not np.isfinite(share):
        return None
    return {"low_share": round(float(share), 3), "min_probability": round(float(result.min_probability), 3),
            "low_confidence": bool(result.low_confidence), "fallback": bool(result.fallback),
            "advice": _advice(result)}


def _advice(result: Any) -> str | None:
    """What the operator can do about a low-confidence plan, in one sentence (None for a confident one)."""
    if result.fallback:
        return ("low confidence: the Nav2-like shortest path replaced the student's plan; move the goal or the robot "
                "so that the way between them is open, or sketch and save more demonstrations of this manoeuvre")
    if not result.low_confidence:
        return None
    return (f"low confidence ({100 * float(result.low_share):.0f} % of the path through p < 0.5): move the goal "
            "nearer, inside the student's window ahead of the robot, or turn the robot towards it; compare with the "
            "Nav2-like shortest baseline drawn dashed (a deployment takes it with fallback=shortest); sketch and "
            "save more demonstrations of this manoeuvre to train it")


def _png(rgba: np.ndarray) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(rgba).save(buf, format="PNG", optimize=False, compress_level=1)
    return buf.getvalue()


def _finite_points(value: Any, what: str, n: int | None = None) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise RequestError(f"{what} must be numbers in map-frame metres, got {value!r}") from None
    if n is not None:
        if arr.shape != (n,) or not np.isfinite(arr).all():
            raise RequestError(f"{what} must be {n} finite numbers, got {value!r}")
        return arr
    if what == "waypoints" and arr.ndim in (1, 2) and len(arr) < 2 and (arr.ndim == 1 or arr.shape[1] == 2):
        raise RequestError(f"the sketch has {len(arr)} waypoint{'s' * (len(arr) != 1)}: send at least 2 [x, y] "
                           "points in map-frame metres (the start first, the goal last)")
    if arr.ndim != 2 or arr.shape[1] != 2 or len(arr) < 2 or not np.isfinite(arr).all():
        raise RequestError(f"{what} must be a list of at least 2 [x, y] points in map-frame metres, got "
                           f"{np.shape(arr)} values")
    return arr


@dataclass
class BuildJob:
    """The dataset build in progress (or the last one)."""

    state: str = "idle"  # idle | running | done | failed
    sketches: int = 0
    expected: int = 0  # instances expected from the saved sketches' lengths (for the progress bar)
    instances: int = 0
    started: float = 0.0
    seconds: float = 0.0
    summary: dict[str, Any] = field(default_factory=dict)
    error: str | None = None

    def to_json(self) -> dict[str, Any]:
        seconds = time.perf_counter() - self.started if self.state == "running" else self.seconds
        progress = 1.0 if self.state == "done" else min(0.99, self.instances / self.expected) if self.expected else 0.0
        return {"state": self.state, "sketches": self.sketches, "instances": self.instances,
                "expected_instances": self.expected, "progress": round(progress, 3), "seconds": round(seconds, 2),
                "summary": self.summary, "error": self.error}


class SketchWorkspace:
    """One map, its sketch file ``<out_dir>/sketches.yaml`` and dataset ``<out_dir>/dataset``.

    Args:
        map_spec: a ROS map yaml or a generator spec (``warehouse:1``).
        out_dir: where the sketch file and the dataset go.
        annotation: the annotation config (:func:`annotation_config`); its window, robot and execution sections
            decide how sketches are executed, exactly as ``spade.annotate`` will when building the dataset.
        model: a student checkpoint or ONNX export for "Try the policy" (optional).
        model_dirs: the folders :meth:`load_model` may load model files from (``POST /api/model``); default: the
            working directory, the map's folder and ``out_dir``. ``model``'s folder is always added.
        allow_unsigned: open model exports without an integrity record (:class:`~spade.deploy.student_planner.Planner`'s
            opt-in, the operator's for the session); refused otherwise.
    """

    def __init__(self, map_spec: str, out_dir: str | Path, annotation: Mapping[str, Any],
                 model: str | Path | None = None, device: str = "cpu", overrides: Sequence[str] = (),
                 model_dirs: Sequence[str | Path] | None = None, allow_unsigned: bool = False) -> None:
        self.cfg = dict(annotation)
        self.overrides = list(overrides)
        self.resolution = float(self.cfg["window"]["resolution_m"])
        spec = str(map_spec)
        if parse_procedural(spec) is None:
            path = Path(spec).expanduser()
            if not path.is_file():
                raise FileNotFoundError(f"map {spec!r}: no such file; give a ROS map yaml or a generator spec such "
                                        "as warehouse:1")
            spec = str(path.resolve())
        self.map_ref = spec
        self.source = load_map_sources([spec], self.resolution)[0]
        self.map = self.source.map
        self.ctx = costmap_context(self.source.map_id, self.map.grid, self.map.resolution, self.cfg, self.map.origin)
        self.fit_rule = WindowFitRule.from_config(self.cfg, self.ctx.costmap.resolution)
        self.out_dir = Path(out_dir).expanduser().resolve()
        self.dataset_dir = self.out_dir / "dataset"
        self.build_command = " ".join(["python -m spade.annotate", f"sketches={self.out_dir / 'sketches.yaml'}",
                                       f"out_dir={self.dataset_dir}", *self.overrides])
        self.store = SketchStore(self.out_dir / "sketches.yaml", self.map_ref, self.build_command)
        self.device = device
        self.planner: Any = None
        self.model_path: str | None = None
        self.allow_unsigned = allow_unsigned
        if model_dirs is None:
            model_dirs = [Path.cwd(), self.out_dir, *([] if parse_procedural(spec) else [Path(spec).parent])]
        self.model_dirs = list(dict.fromkeys(Path(d).expanduser().resolve() for d in model_dirs))
        if model:
            self.model_dirs.append(Path(str(model)).expanduser().resolve().parent)  # the operator's own choice
            try:
                self.load_model(model)
            except RequestError as exc:  # at start-up the operator's own file: a user error, one line
                raise ConfigError(f"model_path={model}: {exc}") from None
        self._exec_lock = threading.Lock()
        self._plan_lock = threading.Lock()
        self._build_lock = threading.Lock()
        self.build = BuildJob()
        self._map_png: bytes | None = None
        self._costmap_png: bytes | None = None

    # -- map -------------------------------------------------------------------------------------------------
    def metadata(self) -> dict[str, Any]:
        m = self.map
        robot = self.cfg["robot"]
        return {
            "map": self.map_ref, "map_id": self.source.map_id, "name": m.name,
            "width_px": m.width, "height_px": m.height, "resolution": m.resolution, "origin": list(m.origin),
            "size_m": list(m.size_m),
            "bounds_m": self.bounds_m(),
            "shapes": sorted(SHAPES), "shape_turn_deg": dict(SHAPES),
            "robot": {"radius_m": float(robot["radius_m"]), "inflation_radius_m": float(robot["inflation_radius_m"])},
            "footprint": self.footprint(),
            "window": self.fit_rule.to_json(),  # the page's live fit verdict: the server's rule, its numbers
            "palette": dict(palette.LABELS),
            "execution": {k: self.cfg["execution"][k] for k in ("max_deviation_m", "shape_tolerance_deg")},
            "sketch_file": str(self.store.path), "dataset_dir": str(self.dataset_dir),
            "sketch_file_shown": shown_path(self.store.path),  # the page shows paths relative to the project
            "build_command": self.build_command,
            "model": self.model_info(),
        }

    def footprint(self) -> dict[str, Any]:
        """The robot footprint the page draws: the loaded model's (its file records the footprint its
        demonstrations assumed), else the annotation settings' ``robot`` (what a dataset built here assumes)."""
        robot = self.cfg["robot"]
        own = {"radius_m": float(robot["radius_m"]), "inflation_radius_m": float(robot["inflation_radius_m"])}
        recorded = getattr(self.planner, "footprint", None) if self.planner is not None else None
        if recorded:
            differs = any(abs(float(recorded[k]) - own[k]) > 1e-6 for k in own)
            return {"radius_m": float(recorded["radius_m"]), "inflation_radius_m": float(recorded["inflation_radius_m"]),
                    "source": "model", "assumed": bool(recorded.get("assumed", False)),
                    "differs_from_settings": differs, "settings": own}
        return {**own, "source": "settings", "assumed": False, "differs_from_settings": False, "settings": own}

    def bounds_m(self) -> dict[str, float]:
        """The map's extent in map-frame metres."""
        m = self.map
        return {"x_min": m.origin[0], "y_min": m.origin[1], "x_max": m.origin[0] + m.size_m[0],
                "y_max": m.origin[1] + m.size_m[1]}

    def map_png(self) -> bytes:
        """The map as a greyscale PNG (free white, obstacles black, unknown grey), one pixel per cell."""
        if self._map_png is None:
            grid = self.map.grid
            grey = np.full(grid.shape, 160, np.uint8)
            grey[grid == FREE] = 255
            grey[grid == OCCUPIED] = 0
            self._map_png = _png(np.repeat(grey[..., None], 3, axis=2))
        return self._map_png

    def costmap_png(self) -> bytes:
        """The inflated costmap as a transparent overlay: opaque red where the robot's centre may not go (closer
        to non-free space than the robot radius), fading blue over the inflation band."""
        if self._costmap_png is None:
            cm = self.ctx.costmap
            free = cm.grid == FREE
            rgba = np.zeros((*cm.grid.shape, 4), np.uint8)
            lethal = free & ~np.isfinite(cm.cost)
            rgba[lethal] = (230, 40, 40, 150)
            band = free & np.isfinite(cm.cost) & (cm.cost > 1.0)
            weight = float(self.cfg["execution"]["cost_weight"]) or 1.0
            alpha = np.clip((cm.cost - 1.0) / weight, 0.0, 1.0)
            rgba[band, :3] = (40, 90, 230)
            rgba[band, 3] = (20 + 110 * alpha[band]).astype(np.uint8)
            self._costmap_png = _png(rgba)
        return self._costmap_png

    def _to_px(self, shape: str, waypoints: np.ndarray) -> np.ndarray:
        try:
            return sketch_to_pixels(Sketch("sketch", shape, waypoints), self.map)
        except SketchFileError as exc:
            raise RequestError(str(exc).replace("sketch 'sketch': ", "")) from None

    def _off_map(self, waypoints: np.ndarray) -> list[int]:
        """Indices of the waypoints outside the map (the cells it has)."""
        px = self.map.world_to_pixel(waypoints)
        h, w = self.map.grid.shape
        return np.flatnonzero((px[:, 0] < -0.5) | (px[:, 0] > w - 0.5) | (px[:, 1] < -0.5)
                              | (px[:, 1] > h - 0.5)).tolist()

    def window_of(self, px: np.ndarray, executed: np.ndarray | None = None) -> tuple[Any, dict[str, Any]]:
        """The student's window the sketch (map pixels) puts it in (:func:`sketch_window_fit`, as the page draws it
        while sketching): the fit and, in metres, the window's corners and its margin's."""
        rule = self.fit_rule
        fit = sketch_window_fit(px, executed, rule)
        margin = rule.margin_m / rule.resolution_m
        lo, hi, m_lo, m_hi = -0.5, rule.size_px - 0.5, margin, rule.size_px - 1 - margin
        corners = np.array([[lo, lo], [hi, lo], [hi, hi], [lo, hi]])
        inner = np.array([[m_lo, m_lo], [m_hi, m_lo], [m_hi, m_hi], [m_lo, m_hi]])
        return fit, {"corners_m": self._metres(fit.pose.to_map(corners)),
                     "margin_m": self._metres(fit.pose.to_map(inner)),
                     "outside_waypoints": fit.outside_waypoints, "outside_points": int(len(fit.outside_points)),
                     "fits": fit.fits}

    def _inside(self, xy: np.ndarray, what: str) -> None:
        b = self.bounds_m()
        if not (b["x_min"] <= xy[0] <= b["x_max"] and b["y_min"] <= xy[1] <= b["y_max"]):
            raise RequestError(f"{what} ({xy[0]:.2f}, {xy[1]:.2f}) m lies outside the map, which spans "
                               f"x [{b['x_min']:.2f}, {b['x_max']:.2f}] m, y [{b['y_min']:.2f}, {b['y_max']:.2f}] m")

    # -- sketches --------------------------------------------------------------------------------------------
    def execute(self, shape: Any, waypoints: Any) -> dict[str, Any]:
        """Execute a sketch as ``spade.annotate`` will; the result, accepted or not, as JSON."""
        try:
            shape = check_shape(str(shape))
        except ValueError as exc:
            raise RequestError(str(exc)) from None
        wp = _finite_points(waypoints, "waypoints")
        t0 = time.perf_counter()
        if off := self._off_map(wp):
            b = self.bounds_m()
            named = ", ".join(f"#{i + 1} ({wp[i, 0]:.2f}, {wp[i, 1]:.2f}) m" for i in off)
            return {"accepted": False, "shape": shape, "reason": "sketch_off_map", "detail": "",
                    "message": f"rejected (sketch_off_map): waypoint{'s' * (len(off) > 1)} {named} "
                               f"lie{'s' * (len(off) == 1)} outside map {self.map.name!r}, which spans "
                               f"x [{b['x_min']:.2f}, {b['x_max']:.2f}] m, y [{b['y_min']:.2f}, {b['y_max']:.2f}] m",
                    "path": [], "offending": [], "offending_waypoints": off, "window": None,
                    "execute_ms": round(1e3 * (time.perf_counter() - t0), 1)}
        px = self._to_px(shape, wp)
        with self._exec_lock:
            try:
                executed = execute_operator_sketch(self.ctx, shape, px, self.cfg)
            except Rejection as rej:
                out = self._rejected(shape, px, rej)
            else:
                out = {"accepted": True, "shape": shape, "path": self._metres(executed.points),
                       "length_m": round(executed.length_m, 3), "turn_deg": round(executed.turn_deg, 1),
                       "deviation_m": round(executed.deviation_m, 3),
                       "min_clearance_m": round(executed.min_clearance_m, 3),
                       "message": f"accepted: {executed.length_m:.2f} m, turns {executed.turn_deg:.0f} deg, "
                                  f"at most {executed.deviation_m:.2f} m from the sketch, inside the student's "
                                  "window"}
                out["window"] = self.window_of(px, executed.points)[1]
        out["execute_ms"] = round(1e3 * (time.perf_counter() - t0), 1)
        return out

    def _metres(self, px: np.ndarray) -> list[list[float]]:
        return np.round(self.map.pixel_to_world(np.asarray(px, dtype=np.float64)), 4).tolist()

    def _rejected(self, shape: str, px: np.ndarray, rej: Rejection) -> dict[str, Any]:
        """A rejection in words, with the offending part: waypoints (indices) or points of the executed path."""
        cm = self.ctx.costmap
        res = cm.resolution
        path = getattr(rej, "points", None)
        offending_waypoints: list[int] = []
        offending: np.ndarray = np.zeros((0, 2))
        if rej.reason in ("sketch_off_map", "sketch_off_free"):
            cells = np.rint(px[:, ::-1]).astype(np.int64)
            h, w = cm.cost.shape
            inside = (cells[:, 0] >= 0) & (cells[:, 0] < h) & (cells[:, 1] >= 0) & (cells[:, 1] < w)
            bad = ~inside.copy()
            bad[inside] = ~np.isfinite(cm.cost[cells[inside, 0], cells[inside, 1]])
            offending_waypoints = np.flatnonzero(bad).tolist()
        elif path is not None and rej.reason == "non_free":
            cells = np.clip(np.rint(path[:, ::-1]).astype(np.int64), 0, np.array(cm.grid.shape) - 1)
            offending = path[cm.clearance_px[cells[:, 0], cells[:, 1]] < cm.robot_radius_px]
        elif rej.reason == "window":
            fit, _ = self.window_of(px, path)
            offending_waypoints, offending = fit.outside_waypoints, fit.outside_points
        elif path is not None and rej.reason == "deviation":
            dist, _ = cKDTree(densify(px, 0.5)).query(path)
            offending = path[dist * res > float(self.cfg["execution"]["max_deviation_m"])]
        elif path is not None:
            offending = path
        words = REASONS.get(rej.reason, rej.reason)
        if offending_waypoints:
            words += " (waypoint " + ", ".join(f"#{i + 1}" for i in offending_waypoints) + ")"
        generic = rej.reason in ("sketch_off_map", "sketch_off_free", "no_path", "window")  # the detail repeats
        if rej.reason == "window" and not offending_waypoints and len(offending):
            rule = self.fit_rule
            words += (f" ({len(offending)} points of the executed path less than "
                      f"{max(0.0, rule.path_margin_m - rule.tolerance_m):g} m inside it)")
        message = f"rejected ({rej.reason}): {words}" + (f"; {rej.detail}" if rej.detail and not generic else "")
        return {"accepted": False, "shape": shape, "reason": rej.reason, "detail": rej.detail, "message": message,
                "path": self._metres(path) if path is not None else [],
                "offending": self._metres(offending) if len(offending) else [],
                "offending_waypoints": offending_waypoints, "window": self.window_of(px, path)[1]}

    def save(self, shape: Any, waypoints: Any, name: str | None = None) -> dict[str, Any]:
        """Execute again (the server never trusts a client's result) and append an accepted sketch to the file."""
        t0 = time.perf_counter()
        result = self.execute(shape, waypoints)
        if not result["accepted"]:
            raise RequestError(f"not saved, the sketch is {result['message']}", status=422)
        stats = {k: result[k] for k in ("length_m", "turn_deg", "deviation_m", "min_clearance_m")}
        try:
            entry = self.store.append(result["shape"], _finite_points(waypoints, "waypoints").tolist(), name, stats)
        except StorageError as exc:
            raise RequestError(str(exc), exc.status) from None
        return {"saved": entry, "execution": result, "sketch_file": str(self.store.path),
                "count": len(self.store.list()), "save_ms": round(1e3 * (time.perf_counter() - t0), 1)}

    def sketches(self) -> dict[str, Any]:
        return {"map": self.map_ref, "sketch_file": str(self.store.path), "sketch_file_shown": shown_path(self.store.path),
                "sketches": self.store.list()}

    def delete(self, name: str) -> dict[str, Any]:
        try:
            return {"deleted": self.store.delete(name), "count": len(self.store.list())}
        except StorageError as exc:
            raise RequestError(str(exc), exc.status) from None

    # -- dataset ---------------------------------------------------------------------------------------------
    def start_build(self, wait: bool = False) -> dict[str, Any]:
        """Build ``<out_dir>/dataset`` from the sketch file with ``spade.annotate`` (in a thread)."""
        saved = self.store.list()
        if not saved:
            raise RequestError("no saved sketch to build a dataset from: execute and save a sketch first", status=409)
        with self._build_lock:
            if self.build.state == "running":
                raise RequestError("a dataset build is already running; wait for it (GET /api/build)", status=409)
            spacing = float(self.cfg["instances"]["spacing_m"])
            remaining = float(self.cfg["instances"]["min_remaining_m"])
            expected = sum(max(1, int(((e.get("executed") or {}).get("length_m", 0.0) - remaining) / spacing))
                           for e in saved)
            self.build = BuildJob("running", len(saved), expected, started=time.perf_counter())
        thread = threading.Thread(target=self._build, args=(self.build,), name="spade-sketch-build", daemon=True)
        thread.start()
        if wait:
            thread.join()
        return self.build.to_json()

    def _build(self, job: BuildJob) -> None:
        from tqdm import tqdm

        cfg = {**self.cfg, "sketches": str(self.store.path), "out_dir": str(self.dataset_dir), "overwrite": True,
               "progress": True}
        watcher = threading.Thread(target=self._watch, args=(job, tqdm), daemon=True)
        try:
            watcher.start()
            job.summary = annotate(cfg)
            job.summary["out_dir_shown"] = shown_path(job.summary.get("out_dir", self.dataset_dir))
            job.instances = int(job.summary["instances"])
            job.state = "done"
        except Exception as exc:  # reported to the page, the server keeps running
            log.exception("dataset build failed")
            job.error = f"{type(exc).__name__}: {exc}"
            job.state = "failed"
        finally:
            job.seconds = time.perf_counter() - job.started

    def _watch(self, job: BuildJob, tqdm: Any) -> None:
        """Progress: the instance count of annotate's own progress bar, read while it runs."""
        desc = f"annotate -> {self.dataset_dir}"
        while job.state == "running":
            for bar in list(getattr(tqdm, "_instances", ())):
                if getattr(bar, "desc", "").startswith(desc):
                    job.instances = max(job.instances, int(bar.n))
            time.sleep(0.1)

    # -- policy ----------------------------------------------------------------------------------------------
    def model_info(self) -> dict[str, Any] | None:
        if self.planner is None:
            return None
        h, w = self.planner.image_size
        return {"path": self.model_path, "path_shown": shown_path(self.model_path or ""),
                "image_size": [h, w], "resolution_m": self.planner.resolution,
                "footprint": self.footprint()}

    def load_model(self, path: str | Path) -> dict[str, Any]:
        """Load a student (checkpoint or ONNX) as the planner; a wrong file is a :class:`RequestError`."""
        from spade.deploy.plan_result import PlannerConfigError
        from spade.deploy.student_planner import Planner

        if "\x00" in str(path):  # the OS refuses such a path (ValueError: embedded null byte): a 400, not a 500
            raise RequestError("model path holds a NUL byte, which no file name can; give the path of a student "
                               "checkpoint (.ckpt) or its export (.onnx, .pt)", status=400)
        p = Path(str(path)).expanduser()
        if p.suffix.lower() not in MODEL_SUFFIXES:  # refused before the file is even looked at
            raise RequestError(f"model {p.name!r} is not a model file: give a student checkpoint (.ckpt) from "
                               "python -m spade.train or its export (.onnx, .pt)", status=422)
        resolved = p.resolve()  # symbolic links followed: a link in a model folder to a file elsewhere is refused
        inside = any(resolved.is_relative_to(d) for d in self.model_dirs)
        if not inside or not resolved.is_file():  # one answer for both: no oracle of what exists elsewhere
            raise RequestError(f"model {str(path)!r}: no such file in the model folders "
                               f"({', '.join(str(d) for d in self.model_dirs)}); give a student checkpoint (.ckpt) "
                               "or its export (.onnx, .pt) under one of them (python -m spade.sketch ... "
                               "models=[FOLDER] sets them)", status=404)
        from spade.models.modelfile import read_info

        try:  # a SPADE model file at all? Anything else gets one answer that says nothing about its bytes
            readable = bool(read_info(resolved, required=False))
        except Exception as exc:  # noqa: BLE001 - pickle, zip, protobuf, TorchScript errors alike
            log.warning("model %s could not be read: %s: %s", resolved, type(exc).__name__, exc)
            readable = False
        if not readable:
            raise RequestError(f"model {p.name} cannot be read as a student checkpoint or export; give a .ckpt "
                               "written by python -m spade.train or its .onnx / .pt export", status=422)
        try:
            planner = Planner(resolved, device=self.device, allow_unsigned=self.allow_unsigned)
        except PlannerConfigError as exc:  # a model file, read: what SPADE found in it (its role, its window)
            raise RequestError(f"model {p.name}: {exc}", status=422) from None
        except Exception as exc:  # not a model at all: say so, never what a parser made of its bytes
            log.warning("model %s could not be read: %s: %s", resolved, type(exc).__name__, exc)
            raise RequestError(f"model {p.name} cannot be read as a student checkpoint or export; give a .ckpt "
                               "written by python -m spade.train or its .onnx / .pt export", status=422) from None
        h, w = planner.image_size
        planner.predict(np.zeros((1, 3, h, w), np.float32))  # warm-up: the operator's first plan is not the slow one
        self.planner, self.model_path = planner, str(p.resolve())
        return self.model_info()  # type: ignore[return-value]

    def plan(self, pose: Any, goal: Any) -> dict[str, Any]:
        """The student's plan from a robot pose (x, y, yaw) to a goal (x, y), map-frame metres and radians."""
        if self.planner is None:
            raise RequestError("no model loaded: start python -m spade.sketch MAP model=student.ckpt (or .onnx), "
                               "or POST /api/model {\"path\": ...}", status=409)
        pose = _finite_points(pose, "pose (x, y, yaw)", 3)
        goal = _finite_points(goal, "goal (x, y)", 2)
        self._inside(pose[:2], "robot pose")
        self._inside(goal, "goal")
        with self._plan_lock:  # one query at a time on the planner's network and map cache
            t0 = time.perf_counter()
            result = self.planner.plan(self.map, pose, goal)
            latency = 1e3 * (time.perf_counter() - t0)
        out: dict[str, Any] = {
            "success": bool(result.success), "code": result.code, "reason": result.reason,
            "waypoints": np.round(np.asarray(result.waypoints, dtype=np.float64), 4).tolist(),
            "length_m": round(float(result.length_m), 3), "latency_ms": round(latency, 1),
            "pose": pose.tolist(), "goal": np.asarray(result.goal if result.goal is not None else goal).tolist()[:2],
            "probability": None, "overlay": None,
            "decode": getattr(result, "decode", None),
            "confidence": _confidence(result),
        }
        if result.probability is not None:
            out["probability"] = "data:image/png;base64," + base64.b64encode(
                _png(_heat(np.asarray(result.probability)))).decode()
            out["overlay"] = self._probability_overlay(result)
        out["baselines"] = self._baselines(result)
        return out

    def _probability_overlay(self, result: Any) -> dict[str, Any] | None:
        """The window's path probabilities resampled onto the map cells the window covers (a PNG and its
        bounds in metres), when the result's window maps metres to window pixels."""
        window = getattr(result, "window", None)
        to_window = getattr(window, "to_window", None)
        if to_window is None:
            return None
        prob = np.asarray(result.probability)
        h, w = prob.shape
        corners = np.array([[0, 0], [w - 1, 0], [0, h - 1], [w - 1, h - 1]], dtype=np.float64)
        to_world = getattr(window, "to_world", None)
        if to_world is None:
            return None
        world = np.asarray(to_world(corners))
        m = self.map
        px = m.world_to_pixel(world)
        c0, r0 = np.floor(px.min(axis=0)).astype(int) - 1
        c1, r1 = np.ceil(px.max(axis=0)).astype(int) + 1
        rows, cols = np.mgrid[r0:r1 + 1, c0:c1 + 1]
        cells_m = m.pixel_to_world(np.stack([cols, rows], axis=-1).astype(np.float64))
        win = np.rint(np.asarray(to_window(cells_m))).astype(int)
        inside = (win[..., 0] >= 0) & (win[..., 0] < w) & (win[..., 1] >= 0) & (win[..., 1] < h)
        gh, gw = m.grid.shape
        on_map = (rows >= 0) & (rows < gh) & (cols >= 0) & (cols < gw)
        free = np.zeros(rows.shape, bool)
        free[on_map] = m.grid[rows[on_map], cols[on_map]] == FREE
        inside &= free  # never over obstacles or unknown space: the robot's path cannot lie there
        rgba = np.zeros((*rows.shape, 4), np.uint8)
        p = prob[win[..., 1][inside], win[..., 0][inside]]
        rgba[inside, :3] = palette.rgb(palette.PROBABILITY)
        # the wash only where the student predicts its path (p at the decoder's threshold or above), not over the
        # whole window: opacity from 90 at the threshold to 240 at p = 1
        t = float(getattr(self.planner, "threshold", 0.5))
        rgba[inside, 3] = np.where(p >= t, 90 + 150 * np.clip((p - t) / max(1.0 - t, 1e-6), 0, 1), 0).astype(np.uint8)
        top_left = m.pixel_to_world(np.array([c0 - 0.5, r0 - 0.5], dtype=np.float64))
        bottom_right = m.pixel_to_world(np.array([c1 + 0.5, r1 + 0.5], dtype=np.float64))
        return {"png": "data:image/png;base64," + base64.b64encode(_png(rgba)).decode(), "threshold": t,
                "window_m": np.round(np.asarray(to_world(np.array([[-0.5, -0.5], [w - 0.5, -0.5], [w - 0.5, h - 0.5],
                                                                    [-0.5, h - 0.5]]))), 4).tolist(),
                "x_min": float(top_left[0]), "y_max": float(top_left[1]),
                "x_max": float(bottom_right[0]), "y_min": float(bottom_right[1])}

    def _baselines(self, result: Any) -> list[dict[str, Any]] | None:
        """The classical baselines (:mod:`spade.metrics.baselines`: straight line, Nav2-like shortest path on the
        inflated costmap, heading template) on the student's own window, in map metres; None when that module or
        a window is missing."""
        import importlib.util

        if importlib.util.find_spec("spade.metrics.baselines") is None or result.state is None or result.window is None:
            return None
        from spade.metrics.baselines import baseline_polylines

        t0 = time.perf_counter()
        out = []
        for name, poly in baseline_polylines(np.asarray(result.state), float(self.planner.resolution)).items():
            metres = np.asarray(result.window.to_world(poly)) if poly is not None else np.zeros((0, 2))
            length = float(np.linalg.norm(np.diff(metres, axis=0), axis=1).sum()) if len(metres) > 1 else 0.0
            out.append({"name": name, "success": poly is not None, "waypoints": np.round(metres, 4).tolist(),
                        "length_m": round(length, 3), "colour": palette.predictor_colour(f"baseline-{name}")})
        ms = round(1e3 * (time.perf_counter() - t0), 1)
        for b in out:
            b["all_ms"] = ms
        return out


def _heat(prob: np.ndarray) -> np.ndarray:
    """Path probabilities as an RGB image (black 0 -> magenta -> white 1)."""
    p = np.clip(prob, 0.0, 1.0)
    rgb = np.stack([np.clip(2 * p, 0, 1), np.clip(2 * p - 1, 0, 1), np.clip(1.6 * p, 0, 1)], axis=-1)
    return (255 * rgb).astype(np.uint8)
