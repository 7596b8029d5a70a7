"""A table's results from MLflow: each row's runs over seeds, and the headline comparisons between rows.

Runs are matched to rows by run name (see :mod:`spade.tracking.tables`); a row's baselines and untrained model,
logged as child runs of its run (:mod:`spade.tracking.predictors`), never count as its runs. A row is
the aggregate of its finished runs **at one scale, one run per distinct seed** (the seed is the run's ``cfg/seed``
param): the scale is the one asked for (``scale=``) or else that of the row's latest finished run; of several
finished runs with the same seed the one that ended last counts. Each cell is the mean over those seeds with the
sample standard deviation (``ddof=1``; none for one seed). A row without a finished run is kept as a
:class:`RowResult` that is not ``found``.

The headline comparisons (:func:`compare`) give the relative change of the means and Welch's t-test of the
per-seed values (:func:`spade.experiments.reporting.stats.welch`, two-sided, alpha :data:`ALPHA`);
with fewer than two seeds on either side there is no test ("n=1, no test").
"""

from __future__ import annotations

import math
import statistics
from dataclasses import dataclass, field
from typing import Any

from spade.experiments.reporting.stats import ALPHA, NO_TEST, holm, welch
from spade.tracking.tables import (
    BASELINE_LABELS,
    CELL_METRICS,
    METRICS,
    PREFERENCE_METRICS,
    Table,
    baseline_metric,
    relative_change,
)
from spade.tracking.client import mlflow_client
from spade.tracking.predictors import with_predictor_figures

MISSING = "missing"  # how a row without a finished run reads in every output
TEST_NAME = "Welch's t-test (two-sided, unequal variances, alpha 0.05) over the per-seed values"


@dataclass
class SeedRun:
    """One finished run counted in a row: its seed, run id, end time and metrics."""

    seed: int | None
    run_id: str
    end_time: int | None
    metrics: dict[str, float]
    start_time: int | None = None


@dataclass
class RowResult:
    """One row: the finished runs counted (one per seed, at one scale), their mean per metric, and how many runs the
    row has in all."""

    row: str
    metrics: dict[str, float] = field(default_factory=dict)  # metric key (tables.METRICS) -> mean over the seeds
    run_id: str | None = None  # the latest of the counted runs
    n_runs: int = 0
    n_finished: int = 0
    statuses: tuple[str, ...] = ()
    scale: str | None = None
    end_time: int | None = None  # ms since the epoch, of the latest counted run
    runs: list[SeedRun] = field(default_factory=list)  # the counted runs, in seed order
    n_other_scales: int = 0  # finished runs left out because they are at another scale
    n_other_data: int = 0  # finished runs left out because they trained or tested on other datasets

    @property
    def found(self) -> bool:
        return self.run_id is not None

    @property
    def n(self) -> int:
        """How many seeds the row's figures are over."""
        return len(self.runs)

    @property
    def seeds(self) -> list[int | None]:
        return [r.seed for r in self.runs]

    @property
    def run_ids(self) -> list[str]:
        return [r.run_id for r in self.runs]

    def value(self, key: str) -> float | None:
        """The mean over the seeds (None when no counted run logged it)."""
        v = self.metrics.get(key)
        return None if v is None or math.isnan(v) else v

    def samples(self, key: str) -> list[float]:
        """The per-seed values of ``key`` (runs that did not log it, or logged NaN, left out)."""
        return [r.metrics[key] for r in self.runs if key in r.metrics and not math.isnan(r.metrics[key])]

    def sd(self, key: str) -> float | None:
        """The sample standard deviation over the seeds (``ddof=1``); None with fewer than two values."""
        values = self.samples(key)
        return statistics.stdev(values) if len(values) >= 2 else None


@dataclass
class ComparisonResult:
    title: str
    row: str
    baseline: str
    metric: str
    value: float | None  # the row's mean
    baseline_value: float | None  # the baseline row's mean
    change: float | None  # percent, of the means
    paper: float | None
    paper_source: str
    n: int = 0  # seeds of the row
    baseline_n: int = 0  # seeds of the baseline row
    p_value: float | None = None  # Welch's t-test; None when there is no test
    test: str = NO_TEST  # "p = 0.012", "n=1, no test", ...
    p_holm: float | None = None  # Holm-adjusted over the table's pairwise tests (pairwise); None: not adjusted

    @property
    def significant(self) -> bool | None:
        """True / False at :data:`ALPHA`; None when there is no test."""
        return None if self.p_value is None else self.p_value < ALPHA


def _search_all_runs(client: Any, experiment_id: str, filter_string: str) -> list[Any]:
    """The runs that match, each with its baselines' and untrained model's figures (its child runs) folded back
    under the run's names (``test/baseline/<name>/...``: :func:`spade.tracking.predictors.
    with_predictor_figures`)."""
    runs, token = [], None
    while True:
        page = client.search_runs([experiment_id], filter_string=filter_string, max_results=1000, page_token=token)
        runs.extend(page)
        token = page.token
        if not token:
            return with_predictor_figures(client, runs)


def _seed(run: Any) -> int | None:
    value = run.data.params.get("cfg/seed")
    try:
        return int(value) if value not in (None, "", "None") else None
    except ValueError:
        return None


def _is_predictor_run(run: Any) -> bool:
    """A child run holding a row's baseline or untrained model (tag ``mlflow.parentRunId``:
    :func:`spade.tracking.predictors.is_predictor_run`, not imported here: the tracking package imports
    Lightning), which carries the row's metric names but is none of its seeds."""
    return bool(run.data.tags.get("mlflow.parentRunId"))


def _data_key(run: Any) -> tuple[str, ...] | None:
    """The datasets a run trained, validated and tested on: the digests of its MLflow dataset inputs (the datasets'
    fingerprints, :mod:`spade.tracking.dataset_inputs`); None for a run that logged none."""
    inputs = getattr(getattr(run, "inputs", None), "dataset_inputs", None) or []
    digests = sorted({str(d.dataset.digest) for d in inputs if getattr(d, "dataset", None) is not None})
    return tuple(digests) or None


def _run_metrics(run: Any) -> dict[str, float]:
    metrics = {k: float(run.data.metrics[m.mlflow_key]) for k, m in METRICS.items() if m.mlflow_key in run.data.metrics}
    for name in BASELINE_LABELS:  # the classical baselines on this row's test set, as "<name>/<metric>"
        for key in (*CELL_METRICS, *PREFERENCE_METRICS):
            mlflow_key = baseline_metric(name, key)
            if mlflow_key in run.data.metrics:
                metrics[f"{name}/{key}"] = float(run.data.metrics[mlflow_key])
    return metrics


def _mean(values: list[float]) -> float:
    return math.fsum(values) / len(values)


def fetch_results(table: Table, tracking_uri: str, scale: str | None = None) -> dict[str, RowResult]:
    """One :class:`RowResult` per row of ``table``, from the runs of its MLflow experiment.

    Runs are matched by run name; ``scale`` keeps only runs tagged with that scale (otherwise the scale of the row's
    latest finished run). The finished runs at that scale count once per distinct seed (the latest of each seed).
    """
    client = mlflow_client(tracking_uri)
    results = {row: RowResult(row) for row in table.rows}
    experiment = client.get_experiment_by_name(table.experiment)
    if experiment is None:
        return results
    filter_string = f"tags.scale = '{scale}'" if scale else ""
    by_row: dict[str, list[Any]] = {}
    for run in _search_all_runs(client, experiment.experiment_id, filter_string):
        if _is_predictor_run(run):  # a row's baseline or untrained model (a child run): not a seed of any row
            continue
        by_row.setdefault(run.info.run_name, []).append(run)

    def ended(r: Any) -> tuple[int, int]:
        return (r.info.end_time or 0, r.info.start_time or 0)

    for row, result in results.items():
        runs = by_row.get(row, [])
        finished = [r for r in runs if r.info.status == "FINISHED"]
        result.n_runs, result.n_finished = len(runs), len(finished)
        result.statuses = tuple(sorted({r.info.status for r in runs}))
        if not finished:
            continue
        latest = max(finished, key=ended)
        result.scale = latest.data.tags.get("scale")
        same_scale = [r for r in finished if r.data.tags.get("scale") == result.scale]
        result.n_other_scales = len(finished) - len(same_scale)
        # Seeds of one row are runs on the same data: a run on other datasets (a user's own data under a table's
        # run name, a regenerated dataset) is left out and counted, never averaged in.
        data = _data_key(latest)
        same_data = [r for r in same_scale if data is None or _data_key(r) in (None, data)]
        result.n_other_data = len(same_scale) - len(same_data)
        same_scale = same_data
        by_seed: dict[int | None, Any] = {}
        for run in sorted(same_scale, key=ended):  # the latest run of each seed wins
            by_seed[_seed(run)] = run
        order = sorted(by_seed, key=lambda s: (s is None, s if s is not None else 0))
        result.runs = [SeedRun(s, by_seed[s].info.run_id, by_seed[s].info.end_time, _run_metrics(by_seed[s]),
                               by_seed[s].info.start_time) for s in order]
        result.run_id, result.end_time = latest.info.run_id, latest.info.end_time
        keys = {k for r in result.runs for k in r.metrics}
        result.metrics = {k: _mean(v) for k in keys if (v := result.samples(k))}
    return results


def compare(table: Table, results: dict[str, RowResult]) -> list[ComparisonResult]:
    """The table's headline comparisons, metric by metric: the relative change of the means and Welch's t-test of
    the per-seed values (:func:`welch`)."""
    out = []
    for comp in table.comparisons:
        row, base = results[comp.row], results[comp.baseline]
        for key in comp.metrics:
            value, baseline = row.value(key), base.value(key)
            if key == "params":  # a property of the architecture, the same for every seed: nothing to test
                p, test = None, "no test (fixed by the architecture)"
            elif value is None or baseline is None:
                p, test = None, "no test (missing)"
            else:
                p, test = welch(row.samples(key), base.samples(key))
            out.append(ComparisonResult(comp.title, comp.row, comp.baseline, key, value, baseline,
                                        relative_change(value, baseline), comp.paper.get(key), comp.paper_source,
                                        row.n, base.n, p, test))
    return out


PAIRWISE_METRICS = ("planner_ape_cm", "ape_cm", "planner_plausibility_cm", "planner_commit_rate")
"""The figures the pairwise tests compare: the deciding one (the planner's APE) first, the paper's APE, then the
preference figures where the runs logged them."""


def pairwise(table: Table, results: dict[str, RowResult], metrics: tuple[str, ...] | str = PAIRWISE_METRICS
             ) -> list[ComparisonResult]:
    """Every pair of found rows of one shape whose lines share all labels but the last (Table 1: the approaches of
    one size, the two experts; Tables 2 and 3: all their rows), on each of ``metrics`` that a row of the pair
    logged: the change of the means and Welch's t-test, as in :func:`compare`, with Holm's correction over all of
    them (:func:`holm`, one family). It says which orderings of the table the seeds can tell apart."""
    out = []
    for metric in ((metrics,) if isinstance(metrics, str) else metrics):
        for shape in table.shapes:
            lines = [line for line in table.lines if shape in line.cells and results[line.cells[shape]].found]
            for i, a in enumerate(lines):
                for b in lines[i + 1:]:
                    if a.labels[:-1] != b.labels[:-1]:
                        continue
                    ra, rb = results[a.cells[shape]], results[b.cells[shape]]
                    va, vb = ra.value(metric), rb.value(metric)
                    if va is None and vb is None:
                        continue  # neither logged it (a figure of newer runs)
                    if va is None or vb is None:
                        p, test = None, "no test (missing)"
                    else:
                        p, test = welch(ra.samples(metric), rb.samples(metric))
                    title = f"{' '.join(b.labels)} vs {' '.join(a.labels)}"
                    if len(table.shapes) > 1:
                        title += f" ({shape})"
                    out.append(ComparisonResult(title, rb.row, ra.row, metric, vb, va, relative_change(vb, va), None,
                                                "", rb.n, ra.n, p, test))
    for c, adjusted in zip(out, holm([c.p_value for c in out])):  # one family: the table's pairwise tests
        c.p_holm = adjusted
    return out
