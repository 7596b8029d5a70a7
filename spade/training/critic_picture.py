"""The critic report as one picture: the corruptions of one instance, and the win rates by timestep band."""

from __future__ import annotations

import io

import numpy as np
import torch

from spade.training.visualize import overlay

__all__ = ["critic_picture"]


def critic_picture(metrics: dict[str, float], bands: list[tuple[int, int]], candidates: list[str],
                   state: torch.Tensor | None = None, images: dict[str, torch.Tensor] | None = None,
                   title: str = "") -> np.ndarray:
    """An RGB uint8 picture: on top, one instance's demonstration and each candidate (``images``: name -> (1, H, W)
    in [0, 1], over ``state`` (3, H, W)); below, a table of ``critic/win/<candidate>[/t<lo>-<hi>]`` from
    ``metrics`` (rows: candidates; columns: all timesteps, then each band), green where the demonstration wins."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = [c for c in candidates if f"critic/win/{c}" in metrics]
    cols = ["all"] + [f"{lo}-{hi}" for lo, hi in bands]
    table = np.array([[metrics.get(f"critic/win/{c}", np.nan)]
                      + [metrics.get(f"critic/win/{c}/t{lo:04d}-{hi:04d}", np.nan) for lo, hi in bands]
                      for c in names])
    shown = list(images or {})
    panel_in, title_in, bottom_in = (1.25 if shown else 0.0), 0.35, 0.6
    table_in = 0.26 * len(names) + 0.3
    height = title_in + panel_in + 0.35 + table_in + bottom_in
    width = max(7.0, 1.05 * len(shown) + 0.3)
    fig = plt.figure(figsize=(width, height), dpi=110)
    for i, name in enumerate(shown):  # one row of panels under the title
        w = 0.98 / len(shown)
        ax = fig.add_axes([0.01 + i * w, 1 - (title_in + panel_in) / height, w - 0.008, (panel_in - 0.2) / height])
        ax.imshow(overlay(state, images[name].new_zeros(images[name].shape), images[name]))
        ax.set_title(name, fontsize=8)
        ax.axis("off")
    ax = fig.add_axes([0.16, bottom_in / height, 0.8, table_in / height])
    ax.imshow(np.nan_to_num(table, nan=0.5), cmap="RdYlGn", vmin=0.5, vmax=1.0, aspect="auto")
    for r in range(table.shape[0]):
        for c in range(table.shape[1]):
            ax.text(c, r, "-" if np.isnan(table[r, c]) else f"{table[r, c]:.2f}", ha="center", va="center", fontsize=7)
    ax.set_yticks(range(len(names)), names, fontsize=8)
    ax.set_xticks(range(len(cols)), [f"t {c}" if c != "all" else "all t" for c in cols], fontsize=7)
    ax.set_xlabel("share of instances where the demonstration scores better (green: the critic ranks it first)",
                  fontsize=8)
    if title:
        fig.suptitle(title, fontsize=9, y=1 - 0.08 / height)
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    plt.close(fig)
    buf.seek(0)
    from PIL import Image

    return np.asarray(Image.open(buf).convert("RGB"))
