"""The report's chart (``<table>.png``): the measured cells of a table as grouped bars (mean over seeds, the
sample sd as error bars), the paper's figures as ticks."""

from __future__ import annotations

from pathlib import Path

from spade.deploy.outputs import SOFTWARE
from spade.experiments.reporting.results import MISSING, RowResult
from spade.tracking.tables import CELL_METRICS, METRICS, Table


def plot_table(table: Table, results: dict[str, RowResult], path: Path, paper: bool = True) -> None:
    """Grouped bars, one panel per metric and one bar per line and shape; rows without a value are labelled
    ("missing" or "n/a"), the paper's figures drawn as black ticks."""
    import numpy as np
    from matplotlib.figure import Figure  # not pyplot: no global backend or figure state (notebooks, servers)
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    metrics = [METRICS[k] for k in CELL_METRICS]
    labels = [" ".join(line.labels) for line in table.lines]
    x = np.arange(len(table.lines))
    width = 0.8 / len(table.shapes)
    fig = Figure(figsize=(max(7.0, 2.5 + 0.55 * len(labels) * len(table.shapes)), 2.6 * len(metrics)))
    axes = fig.subplots(len(metrics), 1, sharex=True, squeeze=False)
    for ax, metric in zip(axes[:, 0], metrics):
        for j, shape in enumerate(table.shapes):
            offset = (j - (len(table.shapes) - 1) / 2) * width
            for i, line in enumerate(table.lines):
                row = line.cells.get(shape)
                if row is None:
                    continue
                value = results[row].value(metric.key)
                if value is None:
                    ax.text(x[i] + offset, 0, MISSING if not results[row].found else "n/a", rotation=90,
                            ha="center", va="bottom", fontsize=7, color="grey")
                else:
                    sd = results[row].sd(metric.key)  # the spread over seeds, when there are two or more
                    ax.bar(x[i] + offset, value, width, color=f"C{j}", yerr=sd, capsize=3 if sd else 0)
                figure = line.paper.get(shape, {}).get(metric.key)
                if paper and figure is not None:
                    ax.plot(x[i] + offset, figure, marker="_", color="black", markersize=10, mew=2)
        ax.set_ylabel(metric.label)
        ax.set_ylim(bottom=0)
        ax.grid(axis="y", alpha=0.3)
    axes[-1, 0].set_xticks(x, labels, rotation=30, ha="right", fontsize=8)
    handles = [Patch(color=f"C{j}", label=f"{table.column_label(s)} (measured)") for j, s in enumerate(table.shapes)]
    if paper:
        handles.append(Line2D([], [], color="black", marker="_", linestyle="none", markersize=10, mew=2, label="paper"))
    axes[0, 0].legend(handles=handles, fontsize=7, loc="upper right")
    axes[0, 0].set_title(table.title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110, metadata={"Software": SOFTWARE})  # SPADE's: a rerun may replace it (overwrite=true)
