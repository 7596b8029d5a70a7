"""``python -m spade.plan MAP.yaml start=X,Y goal=X,Y [model=PATH] [key=value ...]``: plan once and show it.

Loads a student (checkpoint or ONNX export; ``model=``, short for ``model_path=``, or the ``SPADE_PLANNER_MODEL``
environment variable), plans from ``start`` to ``goal`` (map-frame metres) on the map with :class:`spade.planner.Planner`, prints the
waypoints (one ``x y`` line each, metres) and writes a PNG: the map around the student's window, the window,
the predicted path probabilities, the start (blue), the goal (red) and the waypoints (green). Exits with status
1 when no path was found (the PNG is written all the same, for debugging).

Examples::

    python -m spade.plan ../shared/maps/turtlebot3/turtlebot3_world.yaml start=-2.0,-0.5 goal=0.5,1.8 model=student.ckpt
    python -m spade.plan warehouse:101 start=3,4 goal=6,6 model=student.onnx out=plan.png planner.far_goal=clip

Before Hydra parses the command line, a leading positional map (a ``.yaml`` path or a ``kind:seed`` spec)
becomes ``map=...`` and ``start=X,Y`` / ``goal=X,Y`` become ``start=[X,Y]`` / ``goal=[X,Y]`` (Hydra would read
a bare comma list as a sweep).
"""

from __future__ import annotations

import logging
import re
import sys
from pathlib import Path
from typing import Any

import hydra
import numpy as np
from omegaconf import DictConfig, OmegaConf
from PIL import Image, ImageDraw

import spade.paths  # noqa: F401  (registers the ${cwd:} resolver)
from spade.maps import FREE, OCCUPIED, OccupancyMap, generate_map, load_ros_map
from spade.planner import Planner, PlanResult

log = logging.getLogger(__name__)

# Hydra options that take a separate value (``--cfg job``): that value is not a positional map.
_VALUE_FLAGS = {"--cfg", "-c", "--package", "-p", "--config-path", "-cp", "--config-name", "-cn",
                "--config-dir", "-cd", "--experimental-rerun"}
_POINT = re.compile(r"^(?P<key>\+?(?:start|goal))=(?P<value>[^\[\]'\"]+,[^\[\]'\"]+)$")


def rewrite_argv(args: list[str]) -> list[str]:
    """The command line as Hydra needs it: ``MAP.yaml`` -> ``map=MAP.yaml``, ``start=X,Y`` -> ``start=[X,Y]``,
    ``model=PATH`` -> ``model_path=PATH``."""
    out: list[str] = []
    skip_next = False
    for arg in args:
        if skip_next:
            out.append(arg)
            skip_next = False
            continue
        if arg in _VALUE_FLAGS:
            skip_next = True
            out.append(arg)
            continue
        point = _POINT.match(arg)
        if arg.startswith("model="):  # `model` is a config group of conf/: the key is model_path
            out.append("model_path=" + arg[len("model="):])
        elif point:
            out.append(f"{point['key']}=[{point['value']}]")
        elif not arg.startswith("-") and "=" not in arg and _looks_like_map(arg):
            if any(a.startswith("map=") for a in args):
                raise SystemExit(f"spade.plan: got the map twice ({arg!r} and a map= argument); give one")
            out.append(f"map={arg}")
        else:
            out.append(arg)
    return out


def _looks_like_map(arg: str) -> bool:
    from spade.annotation.sources import parse_procedural

    return arg.endswith((".yaml", ".yml")) or parse_procedural(arg) is not None


def load_map(spec: str) -> OccupancyMap:
    """A ROS map yaml, or a procedural map from a ``kind:seed`` spec (e.g. ``warehouse:101``)."""
    from spade.annotation.sources import parse_procedural

    proc = parse_procedural(str(spec))
    if proc is not None:
        return generate_map(proc[0], proc[1])
    path = Path(spec).expanduser()
    if not path.is_file():
        raise FileNotFoundError(f"map={spec}: no such file; give a ROS map yaml or a spec like warehouse:101")
    return load_ros_map(path)


def plan_image(m: OccupancyMap, result: PlanResult, context_m: float = 1.0, width_px: int = 640,
               probability: bool = True) -> Image.Image:
    """A picture of a plan over the map: the window and ``context_m`` around it (or around start and goal when
    the query failed before a window was placed)."""
    pts = [p for p in (result.start, result.goal) if p is not None]
    if result.window is not None:
        x0, y0, x1, y1 = result.window.bounds_m
    elif pts:
        arr = np.asarray(pts)
        (x0, y0), (x1, y1) = arr.min(axis=0), arr.max(axis=0)
    else:
        x0, y0 = m.origin[0], m.origin[1]
        x1, y1 = x0 + m.size_m[0], y0 + m.size_m[1]
    corners = m.world_to_pixel(np.array([[x0 - context_m, y1 + context_m], [x1 + context_m, y0 - context_m]]))
    c0, r0 = np.clip(np.floor(corners[0]).astype(int), 0, [m.width - 1, m.height - 1])
    c1, r1 = np.clip(np.ceil(corners[1]).astype(int), 0, [m.width - 1, m.height - 1])
    grid = m.grid[r0:r1 + 1, c0:c1 + 1]
    rgb = np.full((*grid.shape, 3), 150.0)  # unknown: grey
    rgb[grid == FREE] = 255.0
    rgb[grid == OCCUPIED] = 0.0
    if probability and result.probability is not None and result.window is not None:
        rows, cols = np.mgrid[r0:r1 + 1, c0:c1 + 1]
        win = np.rint(result.window.to_window(m.pixel_to_world(np.stack([cols, rows], axis=-1)))).astype(int)
        h, w = result.probability.shape
        inside = (win[..., 0] >= 0) & (win[..., 0] < w) & (win[..., 1] >= 0) & (win[..., 1] < h)
        alpha = np.zeros(grid.shape)
        alpha[inside] = 0.7 * result.probability[win[..., 1][inside], win[..., 0][inside]]
        rgb = rgb * (1 - alpha[..., None]) + alpha[..., None] * np.array([230.0, 0.0, 200.0])
    scale = max(1, int(round(width_px / max(grid.shape[1], 1))))
    img = Image.fromarray(rgb.astype(np.uint8)).resize((grid.shape[1] * scale, grid.shape[0] * scale),
                                                       Image.NEAREST)
    draw = ImageDraw.Draw(img)

    def screen(xy: np.ndarray) -> np.ndarray:
        px = m.world_to_pixel(np.asarray(xy, dtype=np.float64)) - np.array([c0, r0])
        return (px + 0.5) * scale

    if result.window is not None:
        bx0, by0, bx1, by1 = result.window.bounds_m
        (a, b), (c, d) = screen(np.array([[bx0, by1], [bx1, by0]]))
        draw.rectangle([a, b, c, d], outline=(40, 90, 255), width=max(1, scale // 2))
    if len(result.waypoints) >= 2:
        line = [tuple(p) for p in screen(result.waypoints)]
        draw.line(line, fill=(0, 170, 0), width=max(2, scale // 2))
        for x, y in line:
            draw.ellipse([x - scale / 2, y - scale / 2, x + scale / 2, y + scale / 2], fill=(0, 120, 0))
    radius = max(3, scale * 1.5)
    for point, colour in ((result.start, (30, 60, 255)), (result.goal, (230, 30, 30))):
        if point is not None:
            x, y = screen(point)
            draw.ellipse([x - radius, y - radius, x + radius, y + radius], fill=colour, outline=(0, 0, 0))
    return img


def plan(cfg: DictConfig) -> tuple[PlanResult, Path]:
    """Run one query of the config; returns the result and the PNG path."""
    if cfg.get("model_path") in (None, ""):
        raise ValueError("no model: pass model=PATH (a student .ckpt from python -m spade.train or its .onnx "
                         "export) or set the SPADE_PLANNER_MODEL environment variable")
    options: dict[str, Any] = OmegaConf.to_container(cfg.planner, resolve=True)  # type: ignore[assignment]
    planner = Planner(cfg.model_path, device=cfg.device, **options)
    m = load_map(cfg.map)
    result = planner.plan(m, list(cfg.start), list(cfg.goal))
    out = Path(cfg.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    pic = cfg.picture
    plan_image(m, result, float(pic.context_m), int(pic.width_px), bool(pic.probability)).save(out)
    return result, out


def report(result: PlanResult, cfg: DictConfig, png: Path) -> str:
    """The text the CLI prints: a header, one ``x y`` line per waypoint (metres), the PNG path."""
    start = ", ".join(f"{v:.3f}" for v in result.start[:2]) if result.start is not None else "?"
    goal = ", ".join(f"{v:.3f}" for v in result.goal[:2]) if result.goal is not None else "?"
    if result.success:
        sub = " (sub-goal towards the requested goal)" if result.subgoal else ""
        lines = [f"# plan on {cfg.map}: start ({start}) -> goal ({goal}){sub}: {len(result.waypoints)} waypoints, "
                 f"{result.length_m:.2f} m", "# x_m y_m"]
        lines += [f"{x:.3f} {y:.3f}" for x, y in result.waypoints]
    else:
        lines = [f"# no plan on {cfg.map}: start ({start}) -> goal ({goal}): {result.code}: {result.reason}"]
    lines.append(f"# picture: {png}")
    return "\n".join(lines)


@hydra.main(version_base="1.3", config_path="../conf", config_name="plan")
def main(cfg: DictConfig) -> None:
    result, png = plan(cfg)
    print(report(result, cfg, png), flush=True)
    if not result.success:
        raise SystemExit(1)


if __name__ == "__main__":
    sys.argv = [sys.argv[0], *rewrite_argv(sys.argv[1:])]
    main()
