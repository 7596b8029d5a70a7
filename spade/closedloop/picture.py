"""One picture of closed-loop episodes: for each, the map around the scenario, the demonstration and its
alternatives, the successive plans and the path the robot drove, titled with the outcome and the APE."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from spade.closedloop.simulate import Episode

__all__ = ["episodes_picture"]


def episodes_picture(episodes: list[Episode], path: str | Path, title: str = "", columns: int = 3,
                     pad_m: float = 0.8) -> Path:
    """Write ``episodes`` as a grid of panels to ``path`` (PNG) and return it."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from spade.metrics.closed_loop import episode_figures

    n = max(len(episodes), 1)
    cols = min(columns, n)
    rows = (n + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(4.6 * cols, 4.6 * rows + 0.4), squeeze=False)
    for ax in axes.ravel():
        ax.set_axis_off()
    for ax, ep in zip(axes.ravel(), episodes):
        sc = ep.scenario
        drawn = np.vstack([sc.demonstration, np.asarray(ep.path)[:, :2]])
        lo, hi = drawn.min(axis=0) - pad_m, drawn.max(axis=0) + pad_m
        m = sc.map
        x0, y0 = m.origin[0], m.origin[1]
        extent = (x0, x0 + m.width * m.resolution, y0, y0 + m.height * m.resolution)
        ax.imshow(np.choose(m.grid, [0.75, 1.0, 0.0]), cmap="gray", vmin=0, vmax=1, extent=extent, origin="upper",
                  interpolation="nearest")
        for alt in sc.alternatives:
            ax.plot(alt[:, 0], alt[:, 1], color="#9ecae1", lw=0.8, alpha=0.6)
        for k, plan in enumerate(p for p in ep.plans if len(p.waypoints) >= 2):
            ax.plot(plan.waypoints[:, 0], plan.waypoints[:, 1], color="#fdae6b", lw=0.9,
                    label="plans" if k == 0 else None)
        ax.plot(sc.demonstration[:, 0], sc.demonstration[:, 1], color="#2171b5", lw=2.0, label="demonstration")
        driven = np.asarray(ep.path)
        ax.plot(driven[:, 0], driven[:, 1], color="#d62728", lw=1.6, label="driven")
        ax.plot(*sc.start[:2], "o", color="#2171b5", ms=5)
        ax.plot(*sc.goal, "*", color="#238b45", ms=11)
        if not ep.success:
            ax.plot(*driven[-1, :2], "x", color="black", ms=9, mew=2)
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
        ax.set_aspect("equal")
        ape = episode_figures(ep)["ape_cm"]
        ax.set_title(f"{sc.scenario_id}\n{ep.outcome}, APE {ape:.1f} cm, {len(ep.plans)} plans", fontsize=10)
    if episodes:
        axes.ravel()[0].legend(loc="lower left", fontsize=8, framealpha=0.8)
    if title:
        fig.suptitle(title, fontsize=12)
    fig.tight_layout()
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out
