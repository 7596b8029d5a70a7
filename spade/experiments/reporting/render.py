"""Markdown for a table's report: the measured table in the paper's layout (mean +/- sd over seeds, the number of
seeds, the classical baselines as reference rows), the paper's own figures, the headline relative changes with
their significance test, the pairwise tests, and the notes on missing or odd rows."""

from __future__ import annotations

from spade.experiments.reporting.results import MISSING, TEST_NAME, ComparisonResult, RowResult
from spade.experiments.reporting.stats import mean_sd, significance
from spade.tracking.tables import (
    BASELINE_LABELS,
    CELL_METRICS,
    METRICS,
    PREFERENCE_METRICS,
    TINY_NOTICE,
    Metric,
    Table,
)
from spade.utils.markdown import markdown_table
from spade.utils.provenance import provenance_lines


def seed_cell(metric: Metric, result: RowResult, key: str) -> str:
    """A row's cell over its seeds: ``12.34 ± 1.20`` over two or more seeds (:func:`~spade.experiments.reporting.
    stats.mean_sd`; a share's ``%`` written once), the value alone over one (or for a baseline, which has no
    spread); ``(1 of 2 seeds; ...)`` when some seeds logged NaN (an APE without any extracted path), never a silent
    mean."""
    values = result.samples(key)
    logged = sum(1 for r in result.runs if key in r.metrics)
    undefined = logged - len(values)  # seeds whose value is NaN (for APE: no path extracted at all)
    of = f" ({logged - undefined} of {logged} seeds; NaN counted as failure)" if undefined else ""
    sd = result.sd(key)
    once = sd is not None and metric.format(sd).endswith("%") and metric.format(result.value(key)).endswith("%")
    return mean_sd(values, (lambda v: metric.format(v)[:-1]) if once else metric.format, metric.format,
                   empty=metric.format(None)) + of


def _cell(result: RowResult, prefix: str = "") -> str:
    if not result.found:
        return MISSING
    if prefix:  # a classical baseline: the same test set for every seed, so one figure
        return " / ".join(METRICS[k].format(result.value(prefix + k)) for k in CELL_METRICS)
    return " / ".join(seed_cell(METRICS[k], result, k) for k in CELL_METRICS)


def _baseline_source(table: Table, results: dict[str, RowResult], shape: str) -> RowResult | None:
    """A found row of ``shape`` that logged the baselines (every row of a shape shares its test set)."""
    for line in table.lines:
        row = line.cells.get(shape)
        if row and results[row].found and any(k.startswith("straight/") for k in results[row].metrics):
            return results[row]
    return None


def losses_to_baselines(result: RowResult) -> list[str]:
    """The baselines this row does not beat by the deciding figure (:mod:`spade.metrics.verdict`): the planner's APE
    with its tail (means over seeds): a baseline with a lower planner APE, or an equal one, or a shorter tail."""
    lost = []
    ape, tail = result.value("planner_ape_cm"), result.value("planner_over_20cm_rate")
    for name, label in BASELINE_LABELS.items():
        b_ape, b_tail = result.value(f"{name}/planner_ape_cm"), result.value(f"{name}/planner_over_20cm_rate")
        if b_ape is None:
            continue
        if ape is None or ape >= b_ape or (tail is not None and b_tail is not None and tail > b_tail):
            lost.append(label)
    return lost


def render_preference(table: Table, results: dict[str, RowResult]) -> str | None:
    """The figures that see a preference, per row and for each baseline (mean ± sd over seeds), where the runs
    logged them (test sets with alternative demonstrations); None when none did."""
    rows = [line for line in table.lines if any(results[line.cells[s]].value("planner_plausibility_cm") is not None
                                                for s in line.cells)]
    if not rows:
        return None
    keys = PREFERENCE_METRICS
    header = [*table.label_columns, "shape", *(METRICS[k].label for k in keys)]
    body = []
    for line in rows:
        for shape in table.shapes:
            r = results.get(line.cells.get(shape, ""), None)
            if r is None or not r.found:
                continue
            body.append([*line.labels, shape, *(seed_cell(METRICS[k], r, k) for k in keys)])
    for name, label in BASELINE_LABELS.items():
        for shape in table.shapes:
            src = _baseline_source(table, results, shape)
            if src is None or src.value(f"{name}/planner_plausibility_cm") is None:
                continue
            labels = ["reference", label, *[""] * (len(table.label_columns) - 2)][: len(table.label_columns)]
            if len(table.label_columns) == 1:
                labels = [f"reference: {label}"]
            body.append([*labels, shape, *(METRICS[k].format(src.value(f"{name}/{k}")) for k in keys)])
    return "\n".join(markdown_table(header, body))


def _paper_cell(figures: dict[str, float]) -> str:
    return " / ".join(METRICS[k].format(figures.get(k)) for k in CELL_METRICS)


def _params_cell(values: list[float | None]) -> str:
    shown = sorted({METRICS["params"].format(v) for v in values if v is not None})
    return " / ".join(shown) if shown else "n/a"


def _header(table: Table, seeds: bool = False) -> list[str]:
    cell = " / ".join(METRICS[k].label for k in CELL_METRICS)
    extra = ["seeds"] if seeds else []
    return [*table.label_columns, *(f"{table.column_label(s)}: {cell}" for s in table.shapes), "params", *extra]


def _seeds_cell(results: list[RowResult]) -> str:
    """The number of seeds of each shape's row (``3``, ``3 / 2``; ``0`` for a missing row)."""
    counts = [str(r.n) for r in results]
    return counts[0] if len(set(counts)) == 1 else " / ".join(counts)


def render_table(table: Table, results: dict[str, RowResult]) -> str:
    """The measured table in the paper's layout (markdown): mean ± sd over the row's seeds (the value alone for one
    seed), the number of seeds, the classical baselines as reference rows; missing rows read ``missing``."""
    body = []
    for line in table.lines:
        cells = [_cell(results[line.cells[s]]) if s in line.cells else "" for s in table.shapes]
        params = [results[line.cells[s]].value("params") for s in table.shapes if s in line.cells]
        seeds = _seeds_cell([results[line.cells[s]] for s in table.shapes if s in line.cells])
        body.append([*line.labels, *cells, _params_cell(params), seeds])
    for name, label in BASELINE_LABELS.items():
        sources = {s: _baseline_source(table, results, s) for s in table.shapes}
        if not any(sources.values()):
            continue
        labels = ["reference", label, *[""] * (len(table.label_columns) - 2)][: len(table.label_columns)]
        if len(table.label_columns) == 1:
            labels = [f"reference: {label}"]
        cells = [_cell(src, f"{name}/") if src else "n/a" for src in sources.values()]
        body.append([*labels, *cells, "0 (no learning)", "(no seed)"])
    return "\n".join(markdown_table(_header(table, seeds=True), body))


def render_paper_table(table: Table) -> str:
    """The paper's figures in the same layout (n/a where the paper gives none)."""
    body = []
    for line in table.lines:
        cells = [_paper_cell(line.paper.get(s, {})) if s in line.cells else "" for s in table.shapes]
        params = [line.paper.get(s, {}).get("params") for s in table.shapes]
        body.append([*line.labels, *cells, _params_cell(params)])
    return "\n".join(markdown_table(_header(table), body))


def _pct(value: float | None) -> str:
    return "n/a" if value is None else f"{value:+.1f}%"


def _change(c: ComparisonResult) -> str:
    change = _pct(c.change)
    if c.change is None and c.baseline_value == 0:
        change = "n/a (baseline 0)"
    if c.significant is False:
        change += " (not significant)"
    return change


def render_comparisons(comparisons: list[ComparisonResult]) -> str:
    """The headline comparisons: the means, their relative change (marked "not significant" when Welch's test does
    not reject at alpha 0.05), the test's wording (``p = ...``, ``n=1, no test``), the seeds and the paper's change."""
    body = []
    for c in comparisons:
        m = METRICS[c.metric]
        body.append([c.title, m.label, m.format(c.value), m.format(c.baseline_value), _change(c), c.test,
                     f"{c.n} / {c.baseline_n}", _pct(c.paper) + ("" if c.paper is None else f" ({c.paper_source})")])
    return "\n".join(markdown_table(["comparison", "metric", "row (mean)", "baseline (mean)", "change", "Welch test",
                                          "seeds", "paper"], body))


def _holm_cell(c: ComparisonResult) -> str:
    return "-" if c.p_holm is None else f"p = {c.p_holm:.3g}, {significance(c.p_holm)}"


def render_pairwise(pairs: list[ComparisonResult]) -> str:
    """The pairwise tests: the means, their change, Welch's test and the same p after Holm's correction over every
    pairwise test of the table (significant only when that adjusted p is below 0.05)."""
    body = [[c.title, METRICS[c.metric].label, METRICS[c.metric].format(c.value),
             METRICS[c.metric].format(c.baseline_value), _change(c), c.test, _holm_cell(c), f"{c.n} / {c.baseline_n}"]
            for c in pairs]
    return "\n".join(markdown_table(["rows", "metric", "first (mean)", "second (mean)", "change", "Welch test",
                                          "Holm-corrected", "seeds"], body))


def significance_statement() -> str:
    return (f"Cells: mean ± sample sd (ddof=1) over the row's seeds, the value alone for one seed. Significance: "
            f"{TEST_NAME}; a change marked (not significant) has p >= 0.05, and with fewer than two seeds on a side "
            "there is no test (n=1, no test).")


def is_tiny(results: dict[str, RowResult], scale: str | None = None) -> bool:
    """Whether the report shows tiny-scale figures (the scale asked for, or any found row's)."""
    return scale == "tiny" or any(r.found and r.scale == "tiny" for r in results.values())


def tiny_notice() -> str:
    return f"**{TINY_NOTICE}**"


def render_notes(table: Table, results: dict[str, RowResult]) -> list[str]:
    """Which rows are missing, which have several runs (and which are counted), which scales are mixed."""
    notes = []
    never = [row for row in table.rows if results[row].n_runs == 0]
    if never:
        notes.append(f"missing, no run: {', '.join(never)} (launch a row with `python -m spade.train "
                     f"+experiment=ROW`, the table with `+experiment={table.composition}`)")
    for row in table.rows:
        r = results[row]
        if not r.found and r.n_runs:
            notes.append(f"{row}: missing, {r.n_runs} run(s), none finished ({', '.join(r.statuses)})")
        elif r.n > 1:
            seeds = ", ".join("?" if s is None else str(s) for s in r.seeds)
            notes.append(f"{row}: {r.n} seeds ({seeds}) at scale {r.scale}, from {r.n_runs} runs "
                         f"({r.n_finished} finished)")
        elif r.n_runs > 1:
            notes.append(f"{row}: {r.n_runs} runs ({r.n_finished} finished); using the latest finished, run {r.run_id}")
        if r.found and r.n_other_data:
            notes.append(f"{row}: {r.n_other_data} finished run(s) on other datasets left out (a row's seeds share "
                         f"their data; the row counts its latest run's datasets)")
        if r.found and r.n_other_scales:
            notes.append(f"{row}: {r.n_other_scales} finished run(s) at other scales left out (the row counts its "
                         f"latest scale, {r.scale}; pass scale=NAME to choose)")
    scales = sorted({r.scale for r in results.values() if r.found and r.scale})
    if len(scales) > 1:
        notes.append(f"rows come from different scales ({', '.join(scales)}); pass scale=NAME to keep one")
    counts = sorted({r.n for r in results.values() if r.found})
    if len(counts) > 1:
        notes.append(f"rows have different numbers of seeds ({', '.join(map(str, counts))}); see the seeds column")
    for row in table.rows:  # whether guidance still acted at the end of training (guided rows only)
        r = results[row]
        if r.found and r.value("margin_active") is not None:
            sd = r.sd("margin_active")
            notes.append(f"{row}: margin active in its last training epoch on {r.value('margin_active'):.0%} of "
                         f"samples" + (f" (sd {sd:.0%} over {r.n} seeds)" if sd is not None else "")
                         + (": guidance had stopped acting, a BC run by then" if r.value("margin_active") == 0 else ""))
    failed = [row for row in table.rows if results[row].found and results[row].value("ape_cm") is None]
    if failed:
        notes.append(f"APE n/a: no path could be extracted from any test prediction of {', '.join(failed)} "
                     "(see test/failure_rate in the CSV)")
    for row in table.rows:
        r = results[row]
        if r.found and (lost := losses_to_baselines(r)):
            notes.append(f"{row} LOSES to the {', '.join(lost)} on its own test set by the deciding figure (the "
                         "planner's APE and tail): it has not learned a preference worth deploying")
    if any(r.found and "fid" not in r.metrics for r in results.values()):
        notes.append("FID n/a: the run logged no test/fid (its test set is smaller than the FID extractor needs)")
    return notes


def provenance(table: Table, results: dict[str, RowResult], command: str) -> list[str]:
    """Where the page comes from, as Markdown list items (:func:`spade.utils.provenance.provenance_lines`: the
    command that printed it and the one that launches the table, the code's commit, the date, the machine), with
    the wall time of the runs counted (their sum, and first start to last end). The caller puts a blank line
    before them (Markdown starts no list inside a paragraph)."""
    runs = [r for res in results.values() for r in res.runs]
    spans = [(r.start_time, r.end_time) for r in runs if r.start_time and r.end_time]
    lines = provenance_lines(command, f"python -m spade.train +experiment={table.composition}")
    if spans:
        total = sum(end - start for start, end in spans) / 1000.0
        span = (max(e for _, e in spans) - min(s for s, _ in spans)) / 1000.0
        lines.append(f"- wall time of the {len(spans)} runs counted: {total / 60:.0f} min in all, "
                     f"{span / 3600:.1f} h from the first start to the last end")
    return lines
