"""A small picture of a run's training, epoch by epoch: its losses, its margin's activity, its validation APE.

:func:`epoch_series` reads a finished run's metric history from MLflow and puts every curve on one axis, the
epoch: Lightning logs training and validation metrics at the global step, with an ``epoch`` metric beside each
(the entry of the same step logged closest in time gives the epoch); ``margin/active`` and ``margin/value``,
which ``StudentModule.on_train_epoch_end`` logs with step = epoch, reach MLflow at the global step of that epoch's
validation (SPADE's MLflow logger, :mod:`spade.tracking.logger`, moves them there, so that the UI's
charts line them up with validation; the run's tag ``spade.margin_step=global`` says so), and runs logged before
it keep step = epoch. A training metric logged
several times in an epoch is averaged over it. :func:`progress_picture` draws up to three panels, those the run
has: losses (training and validation), guidance (the share of samples whose margin was active, and the margin's
mean value) and validation APE (with the score that counts failures). :func:`log_progress_picture` logs it as the
run's ``training_progress.png`` artifact.
"""

from __future__ import annotations

import io
import math
from collections import defaultdict
from typing import Any

import numpy as np

PICTURE = "training_progress.png"
LOSS_PREFIXES = ("train/loss", "val/loss")  # train/loss, train/loss_bc, train/loss_dm, val/loss_bc, val/loss (experts)
MARGIN_KEYS = ("margin/active", "margin/value")
APE_KEYS = ("val/ape_cm", "val/score_cm")
BY_EPOCH = MARGIN_KEYS  # logged with step = epoch (runs without the tag MARGIN_STEP_TAG = "global")
MARGIN_STEP_TAG = "spade.margin_step"  # "global": margin/* at the global step of their epoch's validation
FONT_PT = 12


def _epoch_of(history: list[Any]) -> dict[int, list[tuple[int, float]]]:
    """step -> [(timestamp, epoch)] from the ``epoch`` metric's history."""
    out: dict[int, list[tuple[int, float]]] = defaultdict(list)
    for m in history:
        out[int(m.step)].append((int(m.timestamp), float(m.value)))
    return out


def _lookup(epochs: dict[int, list[tuple[int, float]]], step: int, timestamp: int) -> int | None:
    candidates = epochs.get(step)
    if not candidates:
        return None
    return int(min(candidates, key=lambda c: abs(c[0] - timestamp))[1])


def epoch_series(client: Any, run_id: str) -> dict[str, list[tuple[int, float]]]:
    """``{metric: [(epoch, value), ...]}`` for the run's losses, margin activity and validation APE (finite values
    only; a metric logged several times in an epoch is averaged)."""
    run = client.get_run(run_id)
    names = set(run.data.metrics)
    margin_by_epoch = run.data.tags.get(MARGIN_STEP_TAG) != "global"
    wanted = sorted(k for k in names if k.startswith(LOSS_PREFIXES) or k in MARGIN_KEYS or k in APE_KEYS)
    epochs = _epoch_of(client.get_metric_history(run_id, "epoch")) if "epoch" in names else {}
    series: dict[str, list[tuple[int, float]]] = {}
    for key in wanted:
        by_epoch: dict[int, list[float]] = defaultdict(list)
        for m in client.get_metric_history(run_id, key):
            by_step = key in BY_EPOCH and margin_by_epoch
            epoch = int(m.step) if by_step else _lookup(epochs, int(m.step), int(m.timestamp))
            if epoch is not None and math.isfinite(float(m.value)):
                by_epoch[epoch].append(float(m.value))
        if by_epoch:
            series[key] = [(e, sum(v) / len(v)) for e, v in sorted(by_epoch.items())]
    return series


def progress_picture(series: dict[str, list[tuple[int, float]]], title: str | None = None) -> np.ndarray | None:
    """An RGB uint8 picture of ``series`` (:func:`epoch_series`): one panel per group the run logged (losses,
    guidance, validation APE), epochs on the x-axis; None when there is nothing to draw."""
    losses = {k: v for k, v in series.items() if k.startswith(LOSS_PREFIXES)}
    margin = {k: series[k] for k in MARGIN_KEYS if k in series}
    ape = {k: series[k] for k in APE_KEYS if k in series}
    panels = [p for p in (("losses", losses), ("guidance (diffusion margin)", margin),
                          ("validation APE (cm)", ape)) if p[1]]
    if not panels:
        return None
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    fig, axes = plt.subplots(1, len(panels), figsize=(min(4.6 * len(panels), 12.0), 4.0), dpi=100, squeeze=False)
    for ax, (name, group) in zip(axes[0], panels):
        ax.set_title(name, fontsize=FONT_PT)
        ax.set_xlabel("epoch", fontsize=FONT_PT - 1)
        ax.tick_params(labelsize=FONT_PT - 2)
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.grid(alpha=0.3)
        if name.startswith("guidance"):
            if "margin/active" in group:
                e, v = zip(*group["margin/active"])
                ax.plot(e, [100 * x for x in v], "o-", color="tab:red", label="active (% of samples)")
                ax.set_ylim(-5, 105)
                ax.set_ylabel("% of samples with margin > 0")
            if "margin/value" in group:
                twin = ax.twinx()
                e, v = zip(*group["margin/value"])
                twin.plot(e, v, "s--", color="tab:purple", label="mean margin (L_DM)")
                twin.set_ylabel("mean margin (L_DM)")
                handles = ax.get_legend_handles_labels()[0] + twin.get_legend_handles_labels()[0]
                ax.legend(handles=handles, fontsize=FONT_PT - 2, loc="best")
            else:
                ax.legend(fontsize=FONT_PT - 2, loc="best")
            continue
        for key, points in group.items():
            e, v = zip(*points)
            ax.plot(e, v, "o-" if key.startswith("val/") else ".-", label=key, markersize=4)
        ax.legend(fontsize=FONT_PT - 2, loc="best")
    if title:
        fig.suptitle(title, fontsize=FONT_PT + 1)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    plt.close(fig)
    buf.seek(0)
    from PIL import Image

    return np.asarray(Image.open(buf).convert("RGB"))


def log_progress_picture(client: Any, run_id: str, title: str | None = None) -> str | None:
    """Draw the run's training progress from its own metric history and log it as ``training_progress.png``;
    returns the artifact path, or None when the run logged nothing to draw."""
    picture = progress_picture(epoch_series(client, run_id), title)
    if picture is None:
        return None
    client.log_image(run_id, picture, artifact_file=PICTURE)
    return PICTURE
