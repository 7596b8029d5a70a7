"""The report's CSV files: one line per row of a table (``<table>.csv``) and one per headline comparison and
metric (``<table>_comparisons.csv``)."""

from __future__ import annotations

import csv
from pathlib import Path

from spade.experiments.reporting.results import MISSING, ComparisonResult, RowResult
from spade.experiments.tables import METRICS, Table


def write_csv(table: Table, results: dict[str, RowResult], path: Path) -> None:
    """One line per row: labels, shape, status, the metrics, the paper's figures and which run was used."""
    keys = list(METRICS)
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["table", *table.label_columns, "shape", "row", "status", *keys,
                    *(f"paper_{k}" for k in keys), "run_id", "n_runs", "n_finished", "scale"])
        for line in table.lines:
            for shape, row in line.cells.items():
                r = results[row]
                paper = line.paper.get(shape, {})
                w.writerow([table.key, *line.labels, shape, row, "ok" if r.found else MISSING,
                            *("" if r.value(k) is None else r.value(k) for k in keys),
                            *(paper.get(k, "") for k in keys), r.run_id or "", r.n_runs, r.n_finished, r.scale or ""])


def write_comparisons_csv(comparisons: list[ComparisonResult], path: Path) -> None:
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["comparison", "row", "baseline", "metric", "value", "baseline_value", "change_pct",
                    "paper_change_pct", "paper_source"])
        for c in comparisons:
            w.writerow([c.title, c.row, c.baseline, c.metric, *("" if v is None else v for v in
                        (c.value, c.baseline_value, c.change, c.paper)), c.paper_source])
