"""``python -m spade.report [table=table1|table2|table3|all] [scale=...]``: a paper table from the MLflow runs.

Reads the runs of a table's MLflow experiment (one run per row, run name = row name; see
:mod:`spade.experiments.tables`), prints the table in the paper's layout as markdown with the paper's
headline comparisons, and writes ``<table>.md``, ``<table>.csv``, ``<table>_comparisons.csv`` and a
``<table>.png`` chart into ``output_dir``. A row without a finished run is shown as missing, never dropped;
a row with several runs uses the latest finished one, and the notes say so.
"""

from __future__ import annotations

import csv
import logging
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import hydra
from omegaconf import DictConfig

import spade.paths  # noqa: F401  (registers the ${cwd:} resolver)
from spade.experiments.tables import (
    BASELINE_LABELS,
    CELL_METRICS,
    METRICS,
    TABLES,
    Table,
    baseline_metric,
    get_table,
    relative_change,
)

log = logging.getLogger(__name__)

MISSING = "missing"


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


def _cell(result: RowResult, prefix: str = "") -> str:
    if not result.found:
        return MISSING
    return " / ".join(METRICS[k].format(result.value(prefix + k)) for k in CELL_METRICS)


def _baseline_source(table: Table, results: dict[str, RowResult], shape: str) -> RowResult | None:
    """A found row of ``shape`` that logged the baselines (every row of a shape shares its test set)."""
    for line in table.lines:
        row = line.cells.get(shape)
        if row and results[row].found and any(k.startswith("straight/") for k in results[row].metrics):
            return results[row]
    return None


def losses_to_baselines(result: RowResult) -> list[str]:
    """The baselines whose test APE (failures aside) or failure rate this row does not beat."""
    lost = []
    ape, fail = result.value("ape_cm"), result.value("failure_rate")
    for name, label in BASELINE_LABELS.items():
        b_ape, b_fail = result.value(f"{name}/ape_cm"), result.value(f"{name}/failure_rate")
        if b_ape is None:
            continue
        if ape is None or ape >= b_ape or (fail is not None and b_fail is not None and fail > b_fail + 0.02):
            lost.append(label)
    return lost


def _paper_cell(figures: dict[str, float]) -> str:
    return " / ".join(METRICS[k].format(figures.get(k)) for k in CELL_METRICS)


def _params_cell(values: list[float | None]) -> str:
    shown = sorted({METRICS["params"].format(v) for v in values if v is not None})
    return " / ".join(shown) if shown else "n/a"


def _markdown_table(header: list[str], body: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(r) + " |" for r in body]
    return "\n".join(lines)


def _header(table: Table) -> list[str]:
    cell = " / ".join(METRICS[k].label for k in CELL_METRICS)
    return [*table.label_columns, *(f"{s}-shape: {cell}" for s in table.shapes), "params"]


def render_table(table: Table, results: dict[str, RowResult]) -> str:
    """The measured table in the paper's layout (markdown); missing rows read ``missing``."""
    body = []
    for line in table.lines:
        cells = [_cell(results[line.cells[s]]) if s in line.cells else "" for s in table.shapes]
        params = [results[line.cells[s]].value("params") for s in table.shapes if s in line.cells]
        body.append([*line.labels, *cells, _params_cell(params)])
    for name, label in BASELINE_LABELS.items():
        sources = {s: _baseline_source(table, results, s) for s in table.shapes}
        if not any(sources.values()):
            continue
        labels = ["reference", label, *[""] * (len(table.label_columns) - 2)][: len(table.label_columns)]
        if len(table.label_columns) == 1:
            labels = [f"reference: {label}"]
        cells = [_cell(src, f"{name}/") if src else "n/a" for src in sources.values()]
        body.append([*labels, *cells, "0 (no learning)"])
    return _markdown_table(_header(table), body)


def render_paper_table(table: Table) -> str:
    """The paper's figures in the same layout (n/a where the paper gives none)."""
    body = []
    for line in table.lines:
        cells = [_paper_cell(line.paper.get(s, {})) if s in line.cells else "" for s in table.shapes]
        params = [line.paper.get(s, {}).get("params") for s in table.shapes]
        body.append([*line.labels, *cells, _params_cell(params)])
    return _markdown_table(_header(table), body)


def _pct(value: float | None) -> str:
    return "n/a" if value is None else f"{value:+.1f}%"


def render_comparisons(comparisons: list[ComparisonResult]) -> str:
    body = []
    for c in comparisons:
        m = METRICS[c.metric]
        change = _pct(c.change)
        if c.change is None and c.baseline_value == 0:
            change = "n/a (baseline 0)"
        body.append([c.title, m.label, m.format(c.value), m.format(c.baseline_value), change,
                     _pct(c.paper) + ("" if c.paper is None else f" ({c.paper_source})")])
    return _markdown_table(["comparison", "metric", "row", "baseline", "change", "paper"], body)


def render_notes(table: Table, results: dict[str, RowResult]) -> list[str]:
    """Which rows are missing, which have several runs (and which one is used), which scales are mixed."""
    notes = []
    never = [row for row in table.rows if results[row].n_runs == 0]
    if never:
        notes.append(f"missing, no run: {', '.join(never)} (launch a row with `python -m spade.train "
                     f"+experiment=ROW`, the table with `+experiment={table.composition}`)")
    for row in table.rows:
        r = results[row]
        if not r.found and r.n_runs:
            notes.append(f"{row}: missing, {r.n_runs} run(s), none finished ({', '.join(r.statuses)})")
        elif r.n_runs > 1:
            notes.append(f"{row}: {r.n_runs} runs ({r.n_finished} finished); using the latest finished, run {r.run_id}")
    scales = sorted({r.scale for r in results.values() if r.found and r.scale})
    if len(scales) > 1:
        notes.append(f"rows come from different scales ({', '.join(scales)}); pass scale=NAME to keep one")
    failed = [row for row in table.rows if results[row].found and results[row].value("ape_cm") is None]
    if failed:
        notes.append(f"APE n/a: no path could be extracted from any test prediction of {', '.join(failed)} "
                     "(see test/failure_rate in the CSV)")
    for row in table.rows:
        r = results[row]
        if r.found and (lost := losses_to_baselines(r)):
            notes.append(f"{row} LOSES to the {', '.join(lost)} on its own test set (APE or failure rate): "
                         "it has not learned a preference worth deploying")
    if any(r.found and "fid" not in r.metrics for r in results.values()):
        notes.append("FID n/a: the run logged no test/fid (its test set is smaller than the FID extractor needs)")
    return notes


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
                    ax.bar(x[i] + offset, value, width, color=f"C{j}")
                figure = line.paper.get(shape, {}).get(metric.key)
                if paper and figure is not None:
                    ax.plot(x[i] + offset, figure, marker="_", color="black", markersize=10, mew=2)
        ax.set_ylabel(metric.label)
        ax.set_ylim(bottom=0)
        ax.grid(axis="y", alpha=0.3)
    axes[-1, 0].set_xticks(x, labels, rotation=30, ha="right", fontsize=8)
    handles = [Patch(color=f"C{j}", label=f"{s}-shape (measured)") for j, s in enumerate(table.shapes)]
    if paper:
        handles.append(Line2D([], [], color="black", marker="_", linestyle="none", markersize=10, mew=2, label="paper"))
    axes[0, 0].legend(handles=handles, fontsize=7, loc="upper right")
    axes[0, 0].set_title(table.title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


@dataclass
class Report:
    table: Table
    results: dict[str, RowResult]
    comparisons: list[ComparisonResult]
    text: str
    files: dict[str, Path]


def build_report(table: Table, tracking_uri: str, output_dir: str | Path | None = None, scale: str | None = None,
                 paper: bool = True, chart: bool = True, log_to_runs: bool = False) -> Report:
    """Fetch, render and (with ``output_dir``) write one table's report; ``log_to_runs`` also logs the chart and
    markdown into each row's MLflow run (``report/``)."""
    results = fetch_results(table, tracking_uri, scale)
    comparisons = compare(table, results)
    found = sum(r.found for r in results.values())
    parts = [f"## {table.title}", "",
             f"MLflow experiment `{table.experiment}` in {tracking_uri}" + (f", scale {scale}" if scale else "")
             + f": {found} of {len(results)} rows have a finished run.", "", render_table(table, results)]
    notes = render_notes(table, results)
    if notes:
        parts += ["", "Notes:", *(f"- {n}" for n in notes)]
    if comparisons:
        parts += ["", "Relative changes (negative = lower):", "", render_comparisons(comparisons)]
    if paper:
        parts += ["", "The paper's figures (its dataset; compare orderings and ratios, not values):", "",
                  render_paper_table(table)]
    files: dict[str, Path] = {}
    if output_dir is not None:
        out = Path(output_dir)
        out.mkdir(parents=True, exist_ok=True)
        files["csv"] = out / f"{table.key}.csv"
        write_csv(table, results, files["csv"])
        if comparisons:
            files["comparisons_csv"] = out / f"{table.key}_comparisons.csv"
            write_comparisons_csv(comparisons, files["comparisons_csv"])
        if chart:
            files["png"] = out / f"{table.key}.png"
            plot_table(table, results, files["png"], paper=paper)
        files["markdown"] = out / f"{table.key}.md"
        parts += ["", "Written: " + ", ".join(str(p) for p in files.values())]
        files["markdown"].write_text("\n".join(parts) + "\n")
    from spade.experiments.tracking import publish_report

    links = publish_report(table, results, tracking_uri, files, log_to_runs)  # UI links; chart into the runs
    parts += ["", *links] if links else []
    return Report(table, results, comparisons, "\n".join(parts), files)


def report(cfg: DictConfig) -> list[Report]:
    """The reports of ``cfg.table`` (one table, or every table with ``table=all``)."""
    tables = list(TABLES.values()) if str(cfg.table) == "all" else [get_table(cfg.table)]
    # `scale` is the config group of conf/scale (so that scale=cpu reads as everywhere else); its name filters runs.
    scale = cfg.scale.name if cfg.get("scale") else None
    return [build_report(t, cfg.tracking_uri, cfg.get("output_dir"), scale, cfg.get("paper", True),
                         cfg.get("chart", True), cfg.get("log_to_runs", True)) for t in tables]


@hydra.main(version_base="1.3", config_path="../conf", config_name="report")
def main(cfg: DictConfig) -> None:
    for rep in report(cfg):
        print(rep.text + "\n", flush=True)


if __name__ == "__main__":
    main()
