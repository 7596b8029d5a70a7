"""The report's CSV files: one line per row of a table (``<table>.csv``: the means, sds and seeds) and one per
headline comparison and metric (``<table>_comparisons.csv``, with Welch's p-value; the pairwise tests too, with
``kind`` = ``pairwise``)."""

from __future__ import annotations

import csv
from pathlib import Path

from spade.experiments.reporting.results import MISSING, ComparisonResult, RowResult
from spade.tracking.tables import BASELINE_LABELS, CELL_METRICS, METRICS, Table


def _blank(v: float | None) -> float | str:
    return "" if v is None else v


def write_csv(table: Table, results: dict[str, RowResult], path: Path) -> None:
    """One line per row: labels, shape, status, the metrics' means and sds over the seeds, the seeds, the paper's
    figures, the classical baselines on the row's test set and which runs were used."""
    keys = list(METRICS)
    base = [f"{name}/{k}" for name in BASELINE_LABELS for k in CELL_METRICS]
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["table", *table.label_columns, "shape", "row", "status", *keys, *(f"{k}_sd" for k in keys),
                    "n_seeds", "seeds", *(f"paper_{k}" for k in keys),
                    *(f"baseline_{k.replace('/', '_')}" for k in base),
                    "run_id", "run_ids", "n_runs", "n_finished", "scale"])
        for line in table.lines:
            for shape, row in line.cells.items():
                r = results[row]
                paper = line.paper.get(shape, {})
                w.writerow([table.key, *line.labels, shape, row, "ok" if r.found else MISSING,
                            *(_blank(r.value(k)) for k in keys), *(_blank(r.sd(k)) for k in keys),
                            r.n, " ".join("" if s is None else str(s) for s in r.seeds),
                            *(paper.get(k, "") for k in keys), *(_blank(r.value(k)) for k in base),
                            r.run_id or "", " ".join(r.run_ids), r.n_runs, r.n_finished, r.scale or ""])


def write_comparisons_csv(comparisons: list[ComparisonResult], path: Path,
                          pairs: list[ComparisonResult] | None = None) -> None:
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["kind", "comparison", "row", "baseline", "metric", "value", "baseline_value", "change_pct",
                    "n", "baseline_n", "p_value", "significant", "test", "paper_change_pct", "paper_source"])
        for kind, items in (("headline", comparisons), ("pairwise", pairs or [])):
            for c in items:
                w.writerow([kind, c.title, c.row, c.baseline, c.metric,
                            *(_blank(v) for v in (c.value, c.baseline_value, c.change)), c.n, c.baseline_n,
                            _blank(c.p_value), "" if c.significant is None else c.significant, c.test,
                            _blank(c.paper), c.paper_source])
