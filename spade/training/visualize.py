"""Pictures of predictions a person can read: per instance, one panel with the prediction over the demonstration.

Each instance is one panel: the occupancy, dimmed (unknown darkest, free dark grey, obstacles light grey), the
predicted path probability as a heat map (inferno: black, purple, red, yellow), the robot's start disc and the goal
in their colours with a marker on each (a triangle at the start, a star at the goal), and on top the demonstration
(green), the test set's plausible alternative demonstrations where the batch has ``alternatives`` (light green,
dashed) and the path extracted from the prediction (cyan, which no value of the heat map takes): a prediction that
misses the demonstration is seen as two lines apart. Colours:
:mod:`spade.utils.palette`. The panel's title gives the instance (its scenario, or worst / median with its index)
and its APE (or the reason extraction failed); a panel of the worst picture says why it is there ("worst: APE
31.0 cm, over 20 cm", "worst: no path (...)"). A title too long for its panel is wrapped, then set smaller, never
cut (:func:`spade.utils.figure_text.fit_text`). Up to four instances sit in one row, more in two rows (the per-epoch
validation picture's eight: four by two); a picture is at most ``MAX_WIDTH_PX`` wide and ``MAX_HEIGHT_PX`` tall,
with titles and the legend (at the top, where MLflow's Artifacts tab shows a picture first) in text that reads at
that size, without zoom. The validation picture shows the first instance of each scenario of the first batches; the
test step keeps the worst instances, each from another scenario (a scenario's instances are near-duplicates), and
the median ones.
"""

from __future__ import annotations

import io
import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import torch

from spade.utils import palette
from spade.utils.figure_text import fit_text
from spade.metrics.extraction import extract_path, marker_centre
from spade.metrics.geometry import polyline_ape

MAX_HEIGHT_PX = 900
MAX_WIDTH_PX = 1200  # what MLflow's artifact view shows at a laptop's width without shrinking it much
COLUMNS_MAX = 4  # instances in one row; more go to a second row
ROWS_MAX = 4  # kept for callers: a picture of up to this many instances is one row of panels
MIN_PANEL_PX = 128
FONT_PT = 12  # titles and legend: 12 pt at 100 dpi, about 16 px high (a title too long for its panel is smaller)
TITLE_IN = 0.7  # room over each panel for its title: up to three lines, wrapped and shrunk to fit
TAIL_CM = 20.0  # the test's tail (spade.metrics.ape.APE's tail_cm): a worst panel over it says so
EXTRACTED_COLOUR = palette.PREDICTION  # cyan: stands out on the inferno heat map (black, purple, red, yellow)


def overlay(state: torch.Tensor, target: torch.Tensor, prob: torch.Tensor | None = None) -> np.ndarray:
    """An RGB uint8 (H, W, 3) picture of one instance: occupancy grey levels, demonstration, robot and goal in
    their palette colours; a prediction, when given, in the prediction's colour with its probability as
    intensity."""
    occ = state[0].float().cpu().numpy()
    grey = np.where(occ >= 0.75, 235.0, np.where(occ >= 0.25, 130.0, 35.0))
    rgb = np.repeat(grey[..., None], 3, axis=2)
    gt = target[0].float().cpu().numpy() > 0.5
    rgb[gt] = palette.rgb(palette.DEMONSTRATION)
    if prob is not None:
        p = prob[0].float().cpu().numpy()[..., None].clip(0, 1)
        rgb = rgb * (1 - p) + np.array(palette.rgb(palette.PREDICTION), dtype=np.float64) * p
    rgb[state[1].cpu().numpy() > 0.5] = palette.rgb(palette.ROBOT)
    rgb[state[2].cpu().numpy() > 0.5] = palette.rgb(palette.GOAL)
    return rgb.clip(0, 255).astype(np.uint8)


def _instance_ape(prob: np.ndarray, state: np.ndarray, waypoints: np.ndarray, resolution: float
                  ) -> tuple[float, np.ndarray | None, str | None, bool]:
    """(APE cm or inf, extracted polyline or None, failure reason or None, whether the path reaches the goal) of
    one prediction."""
    result = extract_path(prob, state[1], state[2], len(waypoints))
    if not result.ok:
        return float("inf"), None, result.failure, False
    return polyline_ape(result.points, waypoints) * resolution * 100.0, result.points, None, result.reached_goal


def _alternatives_of(alternatives: Any, i: int) -> list[np.ndarray]:
    """Instance ``i``'s plausible alternatives as (N, 2) arrays (rows that are all NaN are empty slots)."""
    if alternatives is None:
        return []
    item = alternatives[i]
    if item is None:
        return []
    arr = item.float().cpu().numpy() if isinstance(item, torch.Tensor) else np.asarray(item, dtype=np.float64)
    if arr.ndim == 2:
        arr = arr[None]
    return [a for a in arr if np.isfinite(a).all()]


def panel_image(state: np.ndarray, prob: np.ndarray) -> np.ndarray:
    """An RGB float (H, W, 3) image in [0, 1] of one instance's panel under its lines: the dimmed occupancy, the
    probability heat map where p >= 0.02, the robot and the goal."""
    import matplotlib

    occ = state[0]
    dim = np.where(occ >= 0.75, 0.6, np.where(occ >= 0.25, 0.25, 0.06))
    rgb = np.repeat(dim[..., None], 3, axis=2)
    heat = matplotlib.colormaps[palette.PROBABILITY_CMAP](prob)[..., :3]
    shown = (prob >= 0.02)[..., None]
    rgb = np.where(shown, 0.1 * rgb + 0.9 * heat, rgb)
    rgb[state[1] > 0.5] = np.array(palette.rgb(palette.ROBOT)) / 255.0
    rgb[state[2] > 0.5] = np.array(palette.rgb(palette.GOAL)) / 255.0
    return rgb


def legend_handles(alternatives: bool) -> list[Any]:
    """The legend of a prediction picture: every colour it uses, named."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    handles = [Line2D([], [], color=palette.DEMONSTRATION, lw=3, label="demonstration")]
    if alternatives:
        handles.append(Line2D([], [], color=palette.ALTERNATIVE, lw=2.5, ls="--", label="plausible alternative"))
    handles += [Line2D([], [], color=palette.PREDICTION, lw=3, label="path extracted from the prediction"),
                Patch(facecolor="#f8a21c", edgecolor="#50105a", label="predicted probability (dark 0, yellow 1)"),
                Line2D([], [], marker="^", color=palette.ROBOT, markeredgecolor="white", lw=0, markersize=10,
                       label="robot's start (heading up)"),
                Line2D([], [], marker="*", color=palette.GOAL, markeredgecolor="white", lw=0, markersize=13,
                       label="goal")]
    return handles


FAILURES = {"empty": "nothing above p 0.5", "too_short": "path too short"}  # extract_path's reasons, in words


def _failure_words(failure: str | None) -> str:
    return FAILURES.get(str(failure), str(failure).replace("_", " "))


def worst_reason(ape_cm: float, failure: str | None, reached_goal: bool, tail_cm: float = TAIL_CM) -> str:
    """Why a panel of the worst picture is among the worst, as its title says it: no path (and why), or its APE with
    what makes it bad (over the tail's ``tail_cm``, a path that stops before the goal)."""
    if failure is not None or not math.isfinite(ape_cm):
        return f"worst: no path ({_failure_words(failure)})"
    parts = [f"worst: APE {ape_cm:.1f} cm"]
    if ape_cm > tail_cm:
        parts.append(f"over {tail_cm:g} cm")
    if not reached_goal:
        parts.append("path ends before the goal")
    return ", ".join(parts)


def _draw_markers(ax: Any, state: np.ndarray) -> None:
    """The start (a triangle: the robot, heading up) and the goal (a star) at their markers' centres."""
    for channel, name, marker, colour, size in ((1, "start", "^", palette.ROBOT, 11),
                                                (2, "goal", "*", palette.GOAL, 15)):
        try:
            x, y = marker_centre(state[channel], name)
        except ValueError:  # an instance without that marker: nothing to show
            continue
        ax.plot([x], [y], marker=marker, color=colour, markeredgecolor="white", markeredgewidth=1.2,
                markersize=size, lw=0, label=name, zorder=5)


def prediction_figure(state: torch.Tensor, target: torch.Tensor, prob: torch.Tensor,
                      waypoints: torch.Tensor | None = None, resolution: torch.Tensor | float = 0.1,
                      titles: list[str] | None = None, upscale: int = 4, alternatives: Any = None,
                      worst: bool = False, tail_cm: float = TAIL_CM) -> Any:
    """The matplotlib figure of :func:`prediction_grid` (the caller closes it). With ``worst``, each panel's figure
    line is :func:`worst_reason` (tail ``tail_cm``)."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    b, _, h, w = state.shape
    res = np.broadcast_to(np.asarray(resolution.cpu() if isinstance(resolution, torch.Tensor) else resolution,
                                     dtype=np.float64).reshape(-1), (b,))
    columns = b if b <= COLUMNS_MAX else math.ceil(b / 2) if b <= 2 * COLUMNS_MAX else COLUMNS_MAX
    rows = math.ceil(b / columns)
    has_alternatives = any(_alternatives_of(alternatives, i) for i in range(b)) if alternatives is not None else False
    legend_in = 0.8 if columns >= 3 else 1.25  # the legend's rows: two or three of entries
    title_in = TITLE_IN  # up to three lines of title over each panel
    inch = max(1.6, upscale * w / 100.0)
    inch = min(inch, (MAX_WIDTH_PX / 100.0 - 0.3) / columns - 0.15,
               (MAX_HEIGHT_PX / 100.0 - legend_in - 0.2) / rows - title_in)
    inch = max(inch, MIN_PANEL_PX / 100.0)
    gap = 0.15  # inches between panels and at the picture's edges
    width_in = columns * (inch + gap) + gap
    height_in = rows * (inch + title_in) + legend_in + gap
    fig = plt.figure(figsize=(width_in, height_in), dpi=100)
    axes = []
    for k in range(b):  # placed by hand: each panel under its own title lines, the legend above them all
        r, c = divmod(k, columns)
        left = gap + c * (inch + gap)
        bottom = height_in - legend_in - (r + 1) * (inch + title_in) + gap / 2
        axes.append(fig.add_axes((left / width_in, bottom / height_in, inch / width_in, inch / height_in)))
    for k, ax in enumerate(axes):
        ax.set_xticks([])
        ax.set_yticks([])
        st = state[k].float().cpu().numpy()
        p = prob[k, 0].float().cpu().numpy().clip(0, 1)
        ax.imshow(panel_image(st, p), interpolation="nearest")
        for alt in _alternatives_of(alternatives, k):
            ax.plot(alt[:, 0], alt[:, 1], color=palette.ALTERNATIVE, lw=2.0, ls="--")
        name = titles[k] if titles else f"#{k + 1}"
        if waypoints is not None:
            wp = waypoints[k].float().cpu().numpy()
            ax.plot(wp[:, 0], wp[:, 1], color=palette.DEMONSTRATION, lw=2.6)
            ape, extracted, failure, reached = _instance_ape(p, st, wp, float(res[k]))
            if extracted is not None:
                ax.plot(extracted[:, 0], extracted[:, 1], color=palette.PREDICTION, lw=2.2)
            if worst:
                figure = worst_reason(ape, failure, reached, tail_cm)
            else:
                figure = f"APE {ape:.1f} cm" if extracted is not None else f"no path: {_failure_words(failure)}"
        else:
            demo = target[k, 0].float().cpu().numpy() > 0.5
            ax.imshow(np.ma.masked_where(~demo, demo), cmap=matplotlib.colors.ListedColormap([palette.DEMONSTRATION]),
                      interpolation="nearest")
            figure = "prediction"
        _draw_markers(ax, st)
        ax.set_xlim(-0.5, w - 0.5)
        ax.set_ylim(h - 0.5, -0.5)
        ax.set_title(f"{name}\n{figure}", fontsize=FONT_PT, linespacing=1.1)
    renderer = fig.canvas.get_renderer()
    for size in range(FONT_PT - 1, 5, -1):  # the largest legend that fits the picture's width
        legend = fig.legend(handles=legend_handles(has_alternatives), loc="upper center",
                            ncol=3 if columns >= 3 else 2, fontsize=size, facecolor="#777777", framealpha=1.0,
                            labelcolor="white", handlelength=2.2)
        if legend.get_window_extent(renderer).width <= fig.bbox.width - 4 or size == 6:
            break
        legend.remove()
    pad_px = 8.0  # the title's pad above its panel, and a little air
    for ax in axes:
        fit_text(ax.title, renderer, (inch + gap * 0.8) * fig.dpi, title_in * fig.dpi - pad_px, max_lines=3)
    return fig


def prediction_grid(state: torch.Tensor, target: torch.Tensor, prob: torch.Tensor,
                    waypoints: torch.Tensor | None = None, resolution: torch.Tensor | float = 0.1,
                    titles: list[str] | None = None, upscale: int = 4, alternatives: Any = None,
                    worst: bool = False, tail_cm: float = TAIL_CM) -> np.ndarray:
    """An RGB uint8 picture of a batch (B, ...) (see the module docstring): one panel per instance, up to
    ``COLUMNS_MAX`` in a row, each at least ``MIN_PANEL_PX`` pixels, the legend at the top. ``alternatives``: per
    instance, the test set's plausible alternatives ((K, N, 2) with all-NaN rows for empty slots, or None).
    ``target`` (the demonstration's raster) is drawn as the demonstration when there are no waypoints. ``worst``:
    the panels are the test's worst, and each title says why (:func:`worst_reason`)."""
    import matplotlib.pyplot as plt
    from PIL import Image

    fig = prediction_figure(state, target, prob, waypoints, resolution, titles, upscale, alternatives, worst, tail_cm)
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    plt.close(fig)
    buf.seek(0)
    return np.asarray(Image.open(buf).convert("RGB"))


class TestRecords:
    """Per-instance APE of a test epoch plus compact copies of the instances, to draw the worst and the median."""

    def __init__(self, tail_cm: float = TAIL_CM) -> None:
        self.tail_cm = float(tail_cm)  # the test's tail, which a worst panel's title compares its APE with
        self.apes: list[float] = []
        self.items: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float]] = []
        self.scenarios: list[str | None] = []
        self.alternatives: list[np.ndarray | None] = []  # the test set's plausible alternatives, when it has them

    @property
    def count(self) -> int:
        return len(self.apes)

    def add(self, batch: dict, prob: torch.Tensor) -> None:
        state = batch["state"].detach().float().cpu().numpy()
        path = batch["path"].detach().float().cpu().numpy()
        p = prob.detach().float().cpu().numpy().clip(0, 1)
        wps = batch["waypoints"].detach().float().cpu().numpy()
        res = np.broadcast_to(np.asarray(batch["resolution"].cpu() if isinstance(batch["resolution"], torch.Tensor)
                                         else batch["resolution"], dtype=np.float64).reshape(-1), (len(state),))
        scenarios = batch.get("scenario_id")
        alternatives = batch.get("alternatives")
        if isinstance(alternatives, torch.Tensor):
            alternatives = alternatives.detach().float().cpu().numpy()
        for i in range(len(state)):
            ape, _, _, _ = _instance_ape(p[i, 0], state[i], wps[i], float(res[i]))
            self.apes.append(ape)
            self.scenarios.append(str(scenarios[i]) if scenarios is not None and i < len(scenarios) else None)
            self.alternatives.append(np.asarray(alternatives[i], dtype=np.float32) if alternatives is not None
                                     else None)
            self.items.append(((state[i] * 2).round().astype(np.uint8), (path[i] > 0.5).astype(np.uint8),
                               (p[i] * 255).round().astype(np.uint8), wps[i].astype(np.float32), float(res[i])))

    def _grid(self, indices: list[int], label: str) -> np.ndarray:
        st = torch.from_numpy(np.stack([self.items[i][0] for i in indices]).astype(np.float32) / 2)
        path = torch.from_numpy(np.stack([self.items[i][1] for i in indices]).astype(np.float32))
        prob = torch.from_numpy(np.stack([self.items[i][2] for i in indices]).astype(np.float32) / 255)
        wps = torch.from_numpy(np.stack([self.items[i][3] for i in indices]))
        res = torch.tensor([self.items[i][4] for i in indices])
        worst = label == "worst"  # the reason line says "worst: ..."; the name line needs no label then
        titles = [("" if worst else f"{label} ") + f"#{i}" + (f" ({self.scenarios[i]})" if i < len(self.scenarios)
                                                               and self.scenarios[i] else "") for i in indices]
        alternatives = [self.alternatives[i] if i < len(self.alternatives) else None for i in indices]
        return prediction_grid(st, path, prob, wps, res, titles, alternatives=alternatives, worst=worst,
                               tail_cm=self.tail_cm)

    def pictures(self, n: int = 4) -> dict[str, np.ndarray]:
        """``worst`` and ``median`` pictures of ``n`` instances each (failures count as the worst); the worst come
        from distinct scenarios while there are enough."""
        order = np.argsort(np.asarray(self.apes), kind="stable")
        worst: list[int] = []
        seen: set[str] = set()
        for i in order[::-1]:
            scenario = self.scenarios[int(i)] if int(i) < len(self.scenarios) else None
            if scenario is not None and scenario in seen:
                continue
            seen.add(scenario) if scenario is not None else None
            worst.append(int(i))
            if len(worst) == n:
                break
        worst += [int(i) for i in order[::-1] if int(i) not in worst][: n - len(worst)]
        mid = len(order) // 2
        median = [int(i) for i in order[max(0, mid - n // 2): max(0, mid - n // 2) + n]]
        return {"worst": self._grid(worst, "worst"), "median": self._grid(median, "median")}
