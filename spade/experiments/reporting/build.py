"""One table's report put together: fetch the results, render the markdown, write the CSV, chart and markdown
files, publish into MLflow (:func:`spade.tracking.report.publish_report`); and the reports a
``conf/report.yaml`` config asks for (:func:`report`, what ``python -m spade.report`` runs)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path


from spade.experiments.reporting.chart import plot_table
from spade.experiments.reporting.files import write_comparisons_csv, write_csv
from spade.experiments.reporting.render import (
    is_tiny,
    render_comparisons,
    render_notes,
    render_pairwise,
    render_paper_table,
    render_preference,
    provenance,
    render_table,
    significance_statement,
    tiny_notice,
)
from spade.experiments.reporting.results import ComparisonResult, RowResult, compare, fetch_results, pairwise
from spade.tracking.tables import Table
from spade.utils.provenance import command_line, shown_path
from spade.tracking.report import publish_report
from spade.tracking.tables import METRICS


DECIDING_STATEMENT = (
    "Which figure decides: the planner's APE with its tail (the path a robot drives, decoded by search; a row beats "
    "a baseline when its planner APE is lower and its share over 20 cm no longer), then, where the test set has "
    "alternative demonstrations, plausibility and commitment; the [metrics reference]"
    "(../reference/metrics.md#which-figure-decides) states it for open and closed loop. The paper's APE is its "
    "definition, shown for comparison.")


def summary(pairs: list[ComparisonResult] | None) -> str:
    """The page's finding in a sentence or two: which pairwise orderings of the table's first (deciding) figure the
    seeds tell apart after Holm's correction. It leads the page (and is its line in the results index)."""
    tested = [c for c in pairs or [] if c.metric == pairs[0].metric and c.p_holm is not None] if pairs else []
    if not tested:
        return "No ordering of the rows can be tested yet (fewer than two seeds a row)."
    label = METRICS[tested[0].metric].label
    told = [c for c in tested if c.p_holm < 0.05]
    if not told:
        return (f"The seeds tell none of the {len(tested)} pairwise orderings by {label} apart (Welch's test over "
                "seeds, Holm's correction over the table): the rows plan alike.")
    fmt = METRICS[tested[0].metric].format
    return (f"The seeds tell {len(told)} of {len(tested)} pairwise orderings by {label} apart (Welch's test over "
            "seeds, Holm's correction over the table): "
            + "; ".join(f"{c.title} ({fmt(c.value)} against {fmt(c.baseline_value)})" for c in told)
            + ". The rest are not told apart.")


@dataclass
class Report:
    table: Table
    results: dict[str, RowResult]
    comparisons: list[ComparisonResult]
    text: str
    files: dict[str, Path]
    pairs: list[ComparisonResult] | None = None  # the pairwise tests (results.pairwise)


def build_report(table: Table, tracking_uri: str, output_dir: str | Path | None = None, scale: str | None = None,
                 paper: bool = True, chart: bool = True, log_to_runs: bool = False) -> Report:
    """Fetch, render and (with ``output_dir``) write one table's report; ``log_to_runs`` also logs the chart and
    markdown into each row's MLflow run (``report/``)."""
    results = fetch_results(table, tracking_uri, scale)
    comparisons = compare(table, results)
    pairs = pairwise(table, results)
    found = sum(r.found for r in results.values())
    seeds = sorted({r.n for r in results.values() if r.found})
    parts = [f"# {table.title}", "", summary(pairs), ""]
    if is_tiny(results, scale):
        parts += [tiny_notice(), ""]
    store = shown_path(tracking_uri)  # relative to the project or SPADE_HOME: never the writing machine's path
    parts += [f"MLflow experiment `{table.experiment}` in {store}" + (f", scale {scale}" if scale else "")
              + f": {found} of {len(results)} rows have a finished run"
              + (f", over {seeds[0] if len(seeds) == 1 else f'{seeds[0]}-{seeds[-1]}'} seed(s) each" if seeds else "")
              + ".", "", render_table(table, results), "", significance_statement()]
    parts += ["", DECIDING_STATEMENT]
    preference = render_preference(table, results)
    if preference:
        parts += ["", "The figures that see a preference (test sets with alternative demonstrations: "
                  "spade.metrics.preference):", "", preference]
    notes = render_notes(table, results)
    if notes:
        parts += ["", "Notes:", "", *(f"- {n}" for n in notes)]  # a blank line: Markdown needs one before a list
    if comparisons:
        parts += ["", "Relative changes of the means (negative = lower), with Welch's test:", "",
                  render_comparisons(comparisons)]
    if pairs:
        parts += ["", "Pairwise (which orderings the seeds tell apart), the deciding figure first; Holm's correction "
                  "over every test of the table:", "", render_pairwise(pairs)]
    parts += ["", "Provenance:", "", *provenance(table, results, command_line("spade.report"))]
    if paper and any(line.paper for line in table.lines):
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
            write_comparisons_csv(comparisons, files["comparisons_csv"], pairs)
        if chart:
            files["png"] = out / f"{table.key}.png"
            plot_table(table, results, files["png"], paper=paper)
        files["markdown"] = out / f"{table.key}.md"
        parts += ["", "Written: " + ", ".join(shown_path(p) for p in files.values())]
        files["markdown"].write_text("\n".join(parts) + "\n")
    links = publish_report(table, results, tracking_uri, files, log_to_runs)  # UI links; chart into the runs
    parts += ["", *links] if links else []
    return Report(table, results, comparisons, "\n".join(parts), files, pairs)
