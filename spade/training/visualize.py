"""Pictures of predictions a person can read: per instance, the state with the demonstration, and the prediction.

Each instance is one row of two panels (one column of two when a picture holds more than ``ROWS_MAX``), upscaled: left, the occupancy (unknown dark, free grey, obstacles white)
with the demonstrated path (green), the robot (blue) and the goal (red); right, the predicted path probability as a
heat map over the dimmed occupancy, with the path extracted from it (cyan, which no value of the heat map's
black-red-yellow scale takes) and the demonstration (green, thin) for comparison. The row's title gives the
instance's APE (or the reason extraction failed). The legend is at the top, where MLflow's Artifacts tab shows a
picture first, and a picture is at most ``MAX_HEIGHT_PX`` tall (so that it is read at a glance, not scrolled).
The validation picture shows the first instances of the first batch; the test step keeps the worst instances,
each from another scenario (a scenario's instances are near-duplicates), and the median ones.
"""

from __future__ import annotations

import io

import numpy as np
import torch

from spade.data.polyline import resample_polyline

MAX_HEIGHT_PX = 900
MAX_WIDTH_PX = 1800  # the wide layout (more than ROWS_MAX instances): one column per instance
ROWS_MAX = 4
MIN_PANEL_PX = 128
EXTRACTED_COLOUR = "#00e5ff"  # cyan: stands out on the inferno heat map (black, purple, red, yellow)


def overlay(state: torch.Tensor, target: torch.Tensor, prob: torch.Tensor | None = None) -> np.ndarray:
    """An RGB uint8 (H, W, 3) picture of one instance: occupancy grey levels, demonstration green, robot blue,
    goal red; a prediction, when given, in magenta with its probability as intensity."""
    occ = state[0].float().cpu().numpy()
    grey = np.where(occ >= 0.75, 235.0, np.where(occ >= 0.25, 130.0, 35.0))
    rgb = np.repeat(grey[..., None], 3, axis=2)
    gt = target[0].float().cpu().numpy() > 0.5
    rgb[gt] = [40, 200, 60]
    if prob is not None:
        p = prob[0].float().cpu().numpy()[..., None].clip(0, 1)
        rgb = rgb * (1 - p) + np.array([230.0, 40, 220]) * p
    rgb[state[1].cpu().numpy() > 0.5] = [40, 90, 255]
    rgb[state[2].cpu().numpy() > 0.5] = [240, 40, 40]
    return rgb.clip(0, 255).astype(np.uint8)


def _instance_ape(prob: np.ndarray, state: np.ndarray, waypoints: np.ndarray, resolution: float
                  ) -> tuple[float, np.ndarray | None, str | None]:
    """(APE cm or inf, extracted polyline or None, failure reason or None) of one prediction."""
    from spade.metrics import extract_path, polyline_ape

    result = extract_path(prob, state[1], state[2], len(waypoints))
    if not result.ok:
        return float("inf"), None, result.failure
    return polyline_ape(result.points, waypoints) * resolution * 100.0, result.points, None


def prediction_grid(state: torch.Tensor, target: torch.Tensor, prob: torch.Tensor,
                    waypoints: torch.Tensor | None = None, resolution: torch.Tensor | float = 0.1,
                    titles: list[str] | None = None, upscale: int = 4) -> np.ndarray:
    """An RGB uint8 picture of a batch (B, ...) (see the module docstring): up to ``ROWS_MAX`` instances one row
    each; more (the per-epoch validation picture) one column each, so that every panel keeps at least
    ``MIN_PANEL_PX`` pixels and the legend and titles stay whole."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    b, _, h, w = state.shape
    res = np.broadcast_to(np.asarray(resolution.cpu() if isinstance(resolution, torch.Tensor) else resolution,
                                     dtype=np.float64).reshape(-1), (b,))
    wide = b > ROWS_MAX
    inch = max(1.6, upscale * w / 100.0)
    if wide:  # one column per instance, at most MAX_WIDTH_PX wide, never under MIN_PANEL_PX a panel
        inch = max(MIN_PANEL_PX / 100.0, min(inch, (MAX_WIDTH_PX / 100.0 - 0.4) / b - 0.15))
        fig, grid = plt.subplots(2, b, figsize=(b * (inch + 0.15) + 0.4, 2 * (inch + 0.35) + 0.9), squeeze=False,
                                 dpi=100)
        axes = grid.T  # axes[i] = (state panel, prediction panel) of instance i
        total_height = 2 * (inch + 0.35) + 0.9
    else:
        inch = max(0.5, min(inch, (MAX_HEIGHT_PX / 100.0 - 0.6) / b - 0.35))  # at most MAX_HEIGHT_PX tall
        fig, axes = plt.subplots(b, 2, figsize=(2 * inch + 0.4, b * (inch + 0.35) + 0.6), squeeze=False, dpi=100)
        total_height = b * (inch + 0.35) + 0.6
    for i in range(b):
        st = state[i].float().cpu().numpy()
        p = prob[i, 0].float().cpu().numpy().clip(0, 1)
        left = overlay(state[i], target[i])
        occ = st[0]
        dim = np.where(occ >= 0.75, 0.55, np.where(occ >= 0.25, 0.25, 0.05))
        axes[i, 0].imshow(left, interpolation="nearest")
        axes[i, 1].imshow(dim, cmap="gray", vmin=0, vmax=1, interpolation="nearest")
        axes[i, 1].imshow(np.ma.masked_less(p, 0.02), cmap="inferno", vmin=0, vmax=1, interpolation="nearest",
                          alpha=0.9)
        label = titles[i] if titles else ""
        if waypoints is not None:
            wp = waypoints[i].float().cpu().numpy()
            axes[i, 1].plot(wp[:, 0], wp[:, 1], color="#28c83c", lw=1.0)
            ape, extracted, failure = _instance_ape(p, st, wp, float(res[i]))
            if extracted is not None:
                axes[i, 1].plot(extracted[:, 0], extracted[:, 1], color=EXTRACTED_COLOUR, lw=1.6)
                label = f"{label}  APE {ape:.1f} cm".strip()
            else:
                label = f"{label}  no path: {failure}".strip()
        for ax in axes[i]:
            ax.set_xticks([])
            ax.set_yticks([])
        if wide:
            axes[i, 0].set_title(titles[i] if titles else f"#{i + 1}", fontsize=8)
            axes[i, 1].set_title((label or "prediction").replace(titles[i] if titles else "", "").strip() or
                                 "prediction", fontsize=8)
        else:
            axes[i, 0].set_title("state + demonstration", fontsize=8)
            axes[i, 1].set_title(label or "prediction", fontsize=8)
    if wide:
        axes[0, 0].set_ylabel("state + demonstration", fontsize=8)
        axes[0, 1].set_ylabel("prediction", fontsize=8)
    handles = [Line2D([], [], color="#28c83c", lw=2, label="demonstration"),
               Line2D([], [], color=EXTRACTED_COLOUR, lw=2, label="extracted prediction"),
               Line2D([], [], marker="o", color="#285aff", lw=0, label="robot (heading up)"),
               Line2D([], [], marker="o", color="#f02828", lw=0, label="goal")]
    top = (0.4 if wide else 0.5) / total_height  # the legend's share of the height, at the top
    fig.tight_layout(rect=(0, 0, 1, 1 - top))
    fig.legend(handles=handles, loc="upper center", ncol=4 if wide else 2, fontsize=7, facecolor="#777777",
               framealpha=1.0)
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    plt.close(fig)
    buf.seek(0)
    from PIL import Image

    return np.asarray(Image.open(buf).convert("RGB"))


class TestRecords:
    """Per-instance APE of a test epoch plus compact copies of the instances, to draw the worst and the median."""

    def __init__(self) -> None:
        self.apes: list[float] = []
        self.items: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float]] = []
        self.scenarios: list[str | None] = []

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
        for i in range(len(state)):
            ape, _, _ = _instance_ape(p[i, 0], state[i], wps[i], float(res[i]))
            self.apes.append(ape)
            self.scenarios.append(str(scenarios[i]) if scenarios is not None and i < len(scenarios) else None)
            self.items.append(((state[i] * 2).round().astype(np.uint8), (path[i] > 0.5).astype(np.uint8),
                               (p[i] * 255).round().astype(np.uint8), wps[i].astype(np.float32), float(res[i])))

    def _grid(self, indices: list[int], label: str) -> np.ndarray:
        st = torch.from_numpy(np.stack([self.items[i][0] for i in indices]).astype(np.float32) / 2)
        path = torch.from_numpy(np.stack([self.items[i][1] for i in indices]).astype(np.float32))
        prob = torch.from_numpy(np.stack([self.items[i][2] for i in indices]).astype(np.float32) / 255)
        wps = torch.from_numpy(np.stack([self.items[i][3] for i in indices]))
        res = torch.tensor([self.items[i][4] for i in indices])
        titles = [f"{label} #{i}" for i in indices]
        return prediction_grid(st, path, prob, wps, res, titles)

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
