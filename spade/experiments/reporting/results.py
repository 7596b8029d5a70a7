"""A table's results from MLflow: the run chosen for each row, and the headline comparisons between rows.

Runs are matched to rows by run name (see :mod:`spade.experiments.tables`). A row without a finished run is kept
as a :class:`RowResult` that is not ``found``; of several finished runs the one that ended last is used.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from spade.experiments.tables import (
    BASELINE_LABELS,
    CELL_METRICS,
    METRICS,
    Table,
    baseline_metric,
    relative_change,
)

MISSING = "missing"  # how a row without a finished run reads in every output


@dataclass
class RowResult:
    """The run chosen for one row (or none): its metrics and how many runs the row has."""

    row: str
    metrics: dict[str, float] = field(default_factory=dict)  # metric key (tables.METRICS) -> value
    run_id: str | None = None
    n_runs: int = 0
    n_finished: int = 0
    statuses: tuple[str, ...] = ()
    scale: str | None = None
    end_time: int | None = None  # ms since the epoch

    @property
    def found(self) -> bool:
        return self.run_id is not None

    def value(self, key: str) -> float | None:
        v = self.metrics.get(key)
        return None if v is None or math.isnan(v) else v


@dataclass
class ComparisonResult:
    title: str
    row: str
    baseline: str
    metric: str
    value: float | None
    baseline_value: float | None
    change: float | None  # percent
    paper: float | None
    paper_source: str


def _search_all_runs(client: Any, experiment_id: str, filter_string: str) -> list[Any]:
    runs, token = [], None
    while True:
        page = client.search_runs([experiment_id], filter_string=filter_string, max_results=1000, page_token=token)
        runs.extend(page)
        token = page.token
        if not token:
            return runs


def fetch_results(table: Table, tracking_uri: str, scale: str | None = None) -> dict[str, RowResult]:
    """One :class:`RowResult` per row of ``table``, from the runs of its MLflow experiment.

    Runs are matched by run name; ``scale`` keeps only runs tagged with that scale. Of several finished runs,
    the one that ended last is used.
    """
    from mlflow import MlflowClient

    client = MlflowClient(tracking_uri=tracking_uri)
    results = {row: RowResult(row) for row in table.rows}
    experiment = client.get_experiment_by_name(table.experiment)
    if experiment is None:
        return results
    filter_string = f"tags.scale = '{scale}'" if scale else ""
    by_row: dict[str, list[Any]] = {}
    for run in _search_all_runs(client, experiment.experiment_id, filter_string):
        by_row.setdefault(run.info.run_name, []).append(run)
    for row, result in results.items():
        runs = by_row.get(row, [])
        finished = [r for r in runs if r.info.status == "FINISHED"]
        result.n_runs, result.n_finished = len(runs), len(finished)
        result.statuses = tuple(sorted({r.info.status for r in runs}))
        if not finished:
            continue
        run = max(finished, key=lambda r: (r.info.end_time or 0, r.info.start_time or 0))
        result.run_id, result.end_time = run.info.run_id, run.info.end_time
        result.scale = run.data.tags.get("scale")
        result.metrics = {k: float(run.data.metrics[m.mlflow_key]) for k, m in METRICS.items()
                          if m.mlflow_key in run.data.metrics}
        for name in BASELINE_LABELS:  # the classical baselines on this row's test set, as "<name>/<metric>"
            for key in CELL_METRICS:
                mlflow_key = baseline_metric(name, key)
                if mlflow_key in run.data.metrics:
                    result.metrics[f"{name}/{key}"] = float(run.data.metrics[mlflow_key])
    return results


def compare(table: Table, results: dict[str, RowResult]) -> list[ComparisonResult]:
    """The relative changes of the table's headline comparisons, metric by metric."""
    out = []
    for comp in table.comparisons:
        row, base = results[comp.row], results[comp.baseline]
        for key in comp.metrics:
            value, baseline = row.value(key), base.value(key)
            out.append(ComparisonResult(comp.title, comp.row, comp.baseline, key, value, baseline,
                                        relative_change(value, baseline), comp.paper.get(key), comp.paper_source))
    return out
