"""Pictures and text of a plan (what ``python -m spade.plan`` shows), and the map specs it accepts."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

from spade.deploy.plan_result import PlanResult
from spade.maps import FREE, OCCUPIED, OccupancyMap, generate_map, load_ros_map
from spade.utils import palette
from spade.annotation.sources import parse_procedural

__all__ = ["load_map", "plan_image", "plan_text"]


def load_map(spec: str | Path) -> OccupancyMap:
    """A ROS map yaml, or a procedural map from a ``kind:seed`` spec (e.g. ``warehouse:101``)."""
    proc = parse_procedural(str(spec))
    if proc is not None:
        return generate_map(proc[0], proc[1])
    path = Path(spec).expanduser()
    if not path.is_file():
        raise FileNotFoundError(f"map={spec}: no such file; give a ROS map yaml or a spec like warehouse:101")
    return load_ros_map(path)


def plan_image(m: OccupancyMap, result: PlanResult, context_m: float = 1.0, width_px: int = 640,
               probability: bool = True) -> Image.Image:
    """A picture of a plan over the map: the robot-frame window (blue outline, its top edge ahead of the robot)
    and ``context_m`` around it (or around start and goal when the query failed before a window was placed),
    the predicted path probabilities (magenta), the waypoints (cyan, the prediction's colour; amber when of low
    confidence), the robot (blue, with its heading) and the goal (red): :mod:`spade.utils.palette`."""
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
    rgb = np.full((*grid.shape, 3), float(palette.UNKNOWN_GREY))
    rgb[grid == FREE] = float(palette.FREE_GREY)
    rgb[grid == OCCUPIED] = float(palette.OCCUPIED_GREY)
    if probability and result.probability is not None and result.window is not None:
        rows, cols = np.mgrid[r0:r1 + 1, c0:c1 + 1]
        win = np.rint(result.window.to_window(m.pixel_to_world(np.stack([cols, rows], axis=-1)))).astype(int)
        h, w = result.probability.shape
        inside = (win[..., 0] >= 0) & (win[..., 0] < w) & (win[..., 1] >= 0) & (win[..., 1] < h)
        alpha = np.zeros(grid.shape)
        alpha[inside] = 0.7 * result.probability[win[..., 1][inside], win[..., 0][inside]]
        shade = np.array(palette.rgb(palette.PROBABILITY), dtype=np.float64)
        rgb = rgb * (1 - alpha[..., None]) + alpha[..., None] * shade
    scale = max(1, int(round(width_px / max(grid.shape[1], 1))))
    img = Image.fromarray(rgb.astype(np.uint8)).resize((grid.shape[1] * scale, grid.shape[0] * scale),
                                                       Image.NEAREST)
    draw = ImageDraw.Draw(img)

    def screen(xy: np.ndarray) -> np.ndarray:
        px = m.world_to_pixel(np.asarray(xy, dtype=np.float64)) - np.array([c0, r0])
        return (px + 0.5) * scale

    if result.window is not None:
        outline = [tuple(p) for p in screen(result.window.corners_m)]
        draw.line([*outline, outline[0]], fill=palette.rgb(palette.WINDOW), width=max(1, scale // 2))
    if len(result.waypoints) >= 2:
        # the prediction's cyan: a confident plan; amber: low confidence (or the Nav2-like fallback that replaced it)
        low = bool(getattr(result, "low_confidence", False))
        colour = palette.rgb(palette.LOW_CONFIDENCE if low else palette.PREDICTION)
        dots = tuple(int(0.7 * c) for c in colour)
        line = [tuple(p) for p in screen(result.waypoints)]
        draw.line(line, fill=colour, width=max(2, scale // 2))
        for x, y in line:
            draw.ellipse([x - scale / 2, y - scale / 2, x + scale / 2, y + scale / 2], fill=dots)
    radius = max(3, scale * 1.5)
    if result.pose is not None:
        x, y, yaw = result.pose
        tip = np.array([x, y]) + 3 * radius / scale * m.resolution * np.array([np.cos(yaw), np.sin(yaw)])
        draw.line([tuple(screen(np.array([x, y]))), tuple(screen(tip))], fill=palette.rgb(palette.ROBOT),
                  width=max(2, scale // 2))
    for point, colour in ((result.start, palette.rgb(palette.ROBOT)),
                          (result.goal, palette.rgb(palette.GOAL))):
        if point is not None:
            x, y = screen(point)
            draw.ellipse([x - radius, y - radius, x + radius, y + radius], fill=colour, outline=(0, 0, 0))
    return with_legend(img)


LEGEND = (("plan", palette.rgb(palette.PREDICTION), "line"),
          ("low-confidence plan", palette.rgb(palette.LOW_CONFIDENCE), "line"),
          ("student's window", palette.rgb(palette.WINDOW), "box"),
          ("robot + heading", palette.rgb(palette.ROBOT), "dot"),
          ("goal", palette.rgb(palette.GOAL), "dot"), ("path probability", palette.rgb(palette.PROBABILITY), "shade"),
          ("free / occupied / unknown", None, "cells"))


def with_legend(img: Image.Image) -> Image.Image:
    """``img`` with a legend strip below it: what each colour of a plan picture means."""
    from PIL import ImageFont

    font = ImageFont.load_default()
    row_h = 18
    x, rows, widths = 6, [[]], []
    for label, colour, kind in LEGEND:  # lay the entries out in rows as wide as the picture
        w = 22 + int(ImageDraw.Draw(img).textlength(label, font=font)) + 14
        if x + w > img.width and rows[-1]:
            rows.append([])
            x = 6
        rows[-1].append((x, label, colour, kind))
        x += w
    out = Image.new("RGB", (img.width, img.height + row_h * len(rows) + 6), (255, 255, 255))
    out.paste(img, (0, 0))
    draw = ImageDraw.Draw(out)
    for r, row in enumerate(rows):
        y = img.height + 4 + r * row_h + row_h // 2
        for x0, label, colour, kind in row:
            if kind == "line":
                draw.line([(x0, y), (x0 + 16, y)], fill=colour, width=3)
            elif kind == "box":
                draw.rectangle([x0, y - 5, x0 + 16, y + 5], outline=colour, width=2)
            elif kind == "dot":
                draw.ellipse([x0 + 3, y - 5, x0 + 13, y + 5], fill=colour, outline=(0, 0, 0))
            elif kind == "shade":
                draw.rectangle([x0, y - 5, x0 + 16, y + 5], fill=colour)
            else:
                # the map's free, occupied and unknown cells
                for i, shade in enumerate((palette.FREE_GREY, palette.OCCUPIED_GREY, palette.UNKNOWN_GREY)):
                    draw.rectangle([x0 + 6 * i, y - 5, x0 + 6 * i + 5, y + 5], fill=(shade, shade, shade),
                                   outline=(120, 120, 120))
            draw.text((x0 + 22, y - 6), label, fill=(0, 0, 0), font=font)
    return out


def plan_text(result: PlanResult, map_name: str, png: Path | None = None) -> str:
    """What ``python -m spade.plan`` prints: a header, one ``x y`` line per waypoint (metres), the picture."""
    pose = ", ".join(f"{v:.3f}" for v in result.pose) if result.pose is not None else "?"
    goal = ", ".join(f"{v:.3f}" for v in result.goal[:2]) if result.goal is not None else "?"
    if result.success:
        sub = " (sub-goal towards the requested goal)" if result.subgoal else ""
        lines = [f"# plan on {map_name}: robot ({pose}) -> goal ({goal}){sub}: {len(result.waypoints)} waypoints, "
                 f"{result.length_m:.2f} m"]
        share = getattr(result, "low_share", float("nan"))
        if share == share:  # decoded by search: its confidence
            flag = ("; LOW CONFIDENCE, replaced by the Nav2-like shortest path (fallback=shortest)" if result.fallback
                    else "; LOW CONFIDENCE" if result.low_confidence else "")
            lines.append(f"# decoded by search: {100 * share:.0f} % of its length through p < 0.5, lowest p "
                         f"{result.min_probability:.2f}{flag}")
        lines.append("# x_m y_m")
        lines += [f"{x:.3f} {y:.3f}" for x, y in result.waypoints]
    else:
        lines = [f"# no plan on {map_name}: robot ({pose}) -> goal ({goal}): {result.code}: {result.reason}"]
    if png is not None:
        lines.append(f"# picture: {png}")
    return "\n".join(lines)
