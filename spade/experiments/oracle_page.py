"""The oracle page: where, if anywhere, a teacher teaches (``python -m spade.report table=oracle``).

Every row is a student trained on a site's few demonstrations (``conf/experiment/site_*``) and tested on the science
test set (about 100 scenarios on held-out maps). The rows differ in what teaches: BC alone, BC on the plausible set,
the oracle teacher (the exact denoiser of each instance's plausible set, :mod:`spade.training.oracle`) on the
labelled states or also on the site's unsketched states, the oracle's samples as labels, the shipped neural teacher.
The page leads with its verdict, written from the figures, then shows each row (mean +/- sd over seeds and a 95 %
interval from a bootstrap over test scenarios, :mod:`spade.experiments.reporting.intervals`) between the floor and
the BC ceiling, beside the classical baselines, and tests every row against BC (Welch's test over seeds with Holm's
correction over the page, and a paired bootstrap over scenarios).

It reads run records (:mod:`spade.experiments.run_records`), exported from the MLflow store first when the store
has the page's experiment: the page regenerates from the committed records once the store is gone.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from spade.experiments.oracle_curve import curve_rows, curve_section, curve_series, curve_tests, plot_curve
from spade.experiments.reporting.intervals import Interval, paired_difference, scenario_interval
from spade.experiments.reporting.stats import ALPHA, holm, mean_sd, welch
from spade.experiments.run_records import RunRecord, export_records, load_records, store_exists
from spade.metrics import catalog
from spade.metrics.catalog import BASELINE_ROW_LABELS
from spade.utils.markdown import collapsed, markdown_table
from spade.metrics.verdict import verdicts
from spade.utils.provenance import command_line, provenance_lines, shown_path

__all__ = ["oracle_report"]

DECIDING = "test/planner/ape_cm"
TAIL_CM = 20.0
COLUMNS: tuple[tuple[str, str], ...] = (
    ("test/planner/ape_cm", "planner_ape_cm"),
    ("test/planner/over_20cm_rate", "tail"),
    ("test/planner/plausibility_cm", "planner_plausibility_cm"),
    ("test/planner/commit_rate", "planner_commit"),
)
"""(logged metric, per-instance column or ``tail``) of the rows' main figures; the tail's per-instance value is an
APE over 20 cm or a failure."""
SEED_ONLY: tuple[str, ...] = ("test/planner/ape_over_floor", "test/planner/failure_rate", "closed_loop/success_rate",
                              "closed_loop/ape_cm", "closed_loop/mode_switches", "margin/active")
"""Figures shown as mean +/- sd over seeds only (no per-instance record)."""


def _instance_value(row: Mapping[str, Any], column: str) -> float:
    if column == "tail":
        ape, failed = row.get("planner_ape_cm"), row.get("planner_failed")
        if failed == 1.0 or ape is None or (isinstance(ape, float) and math.isnan(ape)):
            return 1.0
        return float(float(ape) > TAIL_CM)
    value = row.get(column)
    return float("nan") if value is None or value == "" else float(value)


def _interval(instances: list[Mapping[str, Any]], column: str) -> Interval:
    return scenario_interval([str(r.get("scenario", "")) for r in instances],
                             [_instance_value(r, column) for r in instances])


def _by_scenario(instances: list[Mapping[str, Any]], column: str) -> dict[str, list[float]]:
    out: dict[str, list[float]] = {}
    for r in instances:
        out.setdefault(str(r.get("scenario", "")), []).append(_instance_value(r, column))
    return out


def _figure_cell(values: list[float], metric: str) -> str:
    """A figure over seeds as the catalog writes it (a share's spread in per cent, the unit once)."""
    figure = catalog.figure(metric)
    if figure.unit == "share" and len(values) > 1:
        return mean_sd(values, lambda v: f"{100 * v:.0f}") + " %"
    return mean_sd(values, figure.format)


def _values(runs: list[RunRecord], metric: str) -> list[float]:
    return [r.metrics[metric] for r in runs if metric in r.metrics and math.isfinite(r.metrics[metric])]


def _cell(runs: list[RunRecord], metric: str, column: str | None) -> str:
    text = _figure_cell(_values(runs, metric), metric)
    if column is None or text == "n/a":
        return text
    instances = [i for r in runs for i in r.instances]
    if not instances:
        return text
    interval = _interval(instances, column)
    share = column in ("tail", "planner_commit")
    return f"{text} <br>[{interval.format('.2f', percent=share).split('[', 1)[1]}" if not math.isnan(interval.low) \
        else text


def _mean(runs: list[RunRecord], metric: str) -> float | None:
    values = _values(runs, metric)
    return statistics.fmean(values) if values else None


def _reference_rows(runs: list[RunRecord], references: dict[str, list[dict[str, Any]]]) -> list[str]:
    """The floor, the BC ceiling, the decoder's floor and the baselines, with intervals over scenarios."""
    lines = ["| reference | planner APE (cm) [95 % CI] | > 20 cm | plausibility (cm) | commits | APE / floor |",
             "|---|---|---|---|---|---|"]
    floor = _mean(runs, "test/floor_cm")
    if floor is not None:
        lines.append(f"| floor (best single path against one demonstration) | {floor:.2f} | | | | 1.00 |")
    names = [("ceiling", "BC ceiling (the plausible set's mean image, decoded)"),
             ("demo_target", "decoder's floor (the demonstration's own target, decoded)"),
             *((f"baseline/{b}", BASELINE_ROW_LABELS[b]) for b in BASELINE_ROW_LABELS)]
    for key, label in names:
        prefix = f"test/{key}/planner/"
        ape = _mean(runs, prefix + "ape_cm")
        if ape is None:
            continue
        inst = references.get(key, [])
        ape_text = _interval(inst, "planner_ape_cm").format() if inst else f"{ape:.2f}"

        def fmt(metric: str) -> str:
            value = _mean(runs, prefix + metric)
            return "n/a" if value is None else catalog.fmt(f"planner/{metric}", value)
        lines.append(f"| {label} | {ape_text} | {fmt('over_20cm_rate')} | {fmt('plausibility_cm')} | "
                     f"{fmt('commit_rate')} | {fmt('ape_over_floor')} |")
    return lines


def _teacher_rows(teachers: Mapping[str, str], runs: dict[str, list[RunRecord]],
                  references: dict[str, list[dict[str, Any]]], every: list[RunRecord]) -> list[str]:
    """Each teacher as a planner (one sample, the mean of its K samples' maps, their medoid) beside the oracle as a
    planner (one draw of the generator, the medoid of the plausible set): what a neural teacher must reach."""
    lines = ["| planner | planner APE (cm) | > 20 cm | plausibility (cm) | commits |", "|---|---|---|---|---|"]

    def row(label: str, source: list[RunRecord], prefix: str, instances: list[dict[str, Any]] | None) -> None:
        ape = _mean(source, prefix + "ape_cm")
        if ape is None:
            return
        ape_text = _interval(instances, "planner_ape_cm").format() if instances else f"{ape:.2f}"
        cells = [catalog.fmt(f"planner/{k}", _mean(source, prefix + k))
                 for k in ("over_20cm_rate", "plausibility_cm", "commit_rate")]
        lines.append(f"| {label} | {ape_text} | " + " | ".join(cells) + " |")

    for name, label in teachers.items():
        source = runs.get(name, [])
        instances = [i for r in source for i in r.instances]
        row(f"{label}, one sample", source, "test/planner/", instances)
        row(f"{label}, mean of its samples' maps", source, "test/mean_map/planner/", None)
        row(f"{label}, medoid of its samples' paths", source, "test/medoid/planner/", None)
    row("oracle, one draw of the generator", every, "test/oracle_sample/planner/", references.get("oracle_sample"))
    row("oracle, medoid of the plausible set", every, "test/oracle_medoid/planner/", references.get("oracle_medoid"))
    return lines if len(lines) > 2 else []


def _losses(runs: list[RunRecord]) -> list[str]:
    """The baselines a row loses to by the deciding figure (its seeds' mean planner APE and tail)."""
    keys = {k for r in runs for k in r.metrics}
    mean = {k: v for k in keys if (v := _mean(runs, k)) is not None}
    return [catalog.BASELINE_LABELS.get(v.baseline, v.baseline) for v in verdicts(mean, "test") if v.outcome == "loses to"]


def _bases(rows: Mapping[str, Any], against: str, twins: Mapping[str, str]) -> dict[str, str]:
    """The row each row is tested against: its twin (``against_rows``: a small student against the small BC) or
    ``against``; a row that others are tested against is a reference, not tested itself."""
    references = {against, *twins.values()}
    return {name: twins.get(name, against) for name in rows if name not in references}


def _tests(rows: dict[str, list[RunRecord]], bases: Mapping[str, str]) -> dict[str, dict[str, Any]]:
    """Each row against its base (:func:`_bases`) on the deciding figure: Welch over seeds and the paired bootstrap
    over scenarios (the seed-pooled per-scenario means); Holm's correction is applied by :func:`_correct` over the
    page."""
    out: dict[str, dict[str, Any]] = {}
    for name, against in bases.items():
        base = rows.get(against, [])
        p, wording = welch(_values(rows[name], DECIDING), _values(base, DECIDING))
        a = _by_scenario([i for r in rows[name] for i in r.instances], "planner_ape_cm")
        b = _by_scenario([i for r in base for i in r.instances], "planner_ape_cm")
        out[name] = {"p": p, "wording": wording, "paired": paired_difference(a, b) if a and b else None,
                     "against": against, "base_ape": _mean(base, DECIDING)}
    return out


def _correct(*families: Mapping[Any, dict[str, Any]]) -> None:
    """Holm's correction over every distinct test of the page (a test shared by two sections counted once)."""
    tests = list({id(t): t for family in families for t in family.values()}.values())
    for test, adjusted in zip(tests, holm([t["p"] for t in tests])):
        test["holm"] = adjusted


def _significant(test: dict[str, Any]) -> bool:
    """Told apart from the row it is tested against: by Welch's test over seeds after Holm's correction AND by the
    paired bootstrap over scenarios (the seeds' training spread and the test set's sampling both), each where it
    could be computed."""
    holm_p, paired = test.get("holm"), test.get("paired")
    checks = []
    if holm_p is not None:
        checks.append(holm_p < ALPHA)
    if paired is not None and not math.isnan(paired.low):
        checks.append(paired.excludes_zero())
    return bool(checks) and all(checks)


def _outcome(rows: dict[str, list[RunRecord]], name: str, base_ape: float, test: dict[str, Any]) -> str:
    """better / worse / not told apart / one seed: a row against BC by the page's rule."""
    if len(rows[name]) < 2:  # one training seed: its difference may be the seed's, whatever the scenarios say
        return "one seed"
    if not _significant(test):
        return "not told apart"
    ape = _mean(rows[name], DECIDING)
    return "better" if ape is not None and ape < base_ape else "worse"


def _verdict(rows: dict[str, list[RunRecord]], labels: Mapping[str, str], against: str,
             tests: dict[str, dict[str, Any]]) -> list[str]:
    """The page's finding in short sentences, from the figures (the numbers of each test are in the tests table)."""
    base_ape = _mean(rows.get(against, []), DECIDING)
    ceiling = _mean([r for rs in rows.values() for r in rs], "test/ceiling/planner/ape_cm")
    if base_ape is None:
        return [f"No finished run of {labels.get(against, against)}: nothing to compare against."]
    groups: dict[str, list[str]] = {"better": [], "worse": [], "not told apart": [], "one seed": []}
    winners = []
    for name, test in tests.items():
        ape, twin, own_ape = _mean(rows[name], DECIDING), test["against"], test["base_ape"]
        if ape is None or own_ape is None:
            continue
        closed = "" if ceiling is None or own_ape - ceiling <= 0 else \
            f", {100 * (own_ape - ape) / (own_ape - ceiling):.0f} % of the gap"
        twin_text = "" if twin == against else f" against {labels.get(twin, twin)}"
        outcome = _outcome(rows, name, own_ape, test)
        groups[outcome].append(f"{labels.get(name, name)} {ape:.2f} cm ({ape - own_ape:+.2f}{twin_text}{closed})")
        if outcome == "better":
            winners.append(f"{labels.get(name, name)} ({ape:.2f} cm against {own_ape:.2f}{twin_text})")
    rule = ("told apart only when Welch's test over seeds (Holm's correction over the page) and the paired "
            "bootstrap over scenarios agree")
    head = (f"- **Where a teacher teaches here**: {'; '.join(winners)} beat{'s' if len(winners) == 1 else ''} "
            f"{labels.get(against, against)} by the deciding figure, the planner's APE ({rule}); no other row "
            "does."
            if winners else f"- **No row beats BC** by the deciding figure, the planner's APE ({rule}).")
    lines = [head]
    if ceiling is not None:
        lines.append(f"- {labels.get(against, against)} plans at {base_ape:.2f} cm; the BC ceiling is {ceiling:.2f} cm: "
                     f"a gap of {base_ape - ceiling:.2f} cm that a teacher could close.")
    for title, key in (("Better than BC", "better"), ("Worse than BC", "worse"),
                       ("Not told apart from BC", "not told apart"), ("One seed only, not tested over seeds", "one seed")):
        if groups[key]:
            lines.append(f"- **{title}**: " + "; ".join(groups[key]) + ".")
    for name, runs in rows.items():
        lost = _losses(runs)
        if lost:
            lines.append(f"- {labels.get(name, name)} loses to the {', '.join(lost)} by the planner's APE and tail.")
    return lines


HEADLINE: tuple[tuple[str, str, str | None], ...] = (
    ("planner APE (cm) [95 % CI]", "test/planner/ape_cm", "planner_ape_cm"),
    ("> 20 cm", "test/planner/over_20cm_rate", None),
    ("plausibility (cm)", "test/planner/plausibility_cm", None),
    ("commits", "test/planner/commit_rate", None),
    ("closed-loop APE (cm)", "closed_loop/ape_cm", None),
)
"""The headline table's figures (short headers: the table fits the docs column); every figure is in the full table."""


def _headline(rows: dict[str, list[RunRecord]], labels: Mapping[str, str], against: str,
              tests: dict[str, dict[str, Any]]) -> list[str]:
    """One short table: each row's deciding figure with its interval, tail, preference figures, closed loop and its
    outcome against BC."""
    base_ape = _mean(rows.get(against, []), DECIDING)
    body = []
    for name, runs in rows.items():
        cells = []
        for _, metric, column in HEADLINE:
            text = _figure_cell(_values(runs, metric), metric.replace("test/", ""))
            if column is not None and text != "n/a":
                instances = [i for r in runs for i in r.instances]
                interval = _interval(instances, column) if instances else None
                if interval is not None and not math.isnan(interval.low):
                    text = f"{text} [{interval.low:.2f}, {interval.high:.2f}]"
            cells.append(text)
        twin, own_ape = tests.get(name, {}).get("against"), tests.get(name, {}).get("base_ape")
        if own_ape is None or base_ape is None:
            outcome = "—"
        else:
            ape = _mean(runs, DECIDING)
            outcome = f"{ape - own_ape:+.2f} cm, {_outcome(rows, name, own_ape, tests[name])}" \
                if ape is not None else "n/a"
            outcome += "" if twin == against else f" (against {labels.get(twin, twin)})"
        body.append([labels.get(name, name), len(runs), *cells, outcome])
    return markdown_table(["row", "seeds", *(h for h, _, _ in HEADLINE), "against BC"], body)


def _tests_table(rows: dict[str, list[RunRecord]], labels: Mapping[str, str], against: str,
                 tests: dict[str, dict[str, Any]]) -> list[str]:
    """The tests against BC, those told apart first: difference, Welch's p, Holm's p, the paired bootstrap."""
    base_ape = _mean(rows.get(against, []), DECIDING)
    if base_ape is None or not tests:
        return []
    body = []
    order = sorted(tests, key=lambda n: (not _significant(tests[n]), tests[n].get("holm") or 2.0))
    for name in order:
        test, ape = tests[name], _mean(rows[name], DECIDING)
        own_ape = test["base_ape"]
        if ape is None or own_ape is None:
            continue
        p, holm_p, paired = test.get("p"), test.get("holm"), test.get("paired")
        paired_text = "n/a" if paired is None or math.isnan(paired.low) else \
            f"{paired.mean:+.2f} [{paired.low:+.2f}, {paired.high:+.2f}]"
        twin = test["against"]
        label = labels.get(name, name) + ("" if twin == against else f" (against {labels.get(twin, twin)})")
        body.append([label, f"{ape - own_ape:+.2f}", "n/a" if p is None else f"{p:.3g}",
                     "n/a" if holm_p is None else f"{holm_p:.3g}", paired_text, _outcome(rows, name, own_ape, test)])
    return markdown_table(["row", "difference (cm)", "Welch p", "Holm p", "paired over scenarios (cm) [95 % CI]",
                           "outcome"], body)


def _teacher_verdict(teachers: Mapping[str, str], teacher_runs: dict[str, list[RunRecord]],
                    every: list[RunRecord]) -> list[str]:
    """What a neural teacher must reach: each teacher's planner (one sample, medoid) against the oracle's."""
    oracle_one = _mean(every, "test/oracle_sample/planner/ape_cm")
    oracle_medoid = _mean(every, "test/oracle_medoid/planner/ape_cm")
    if oracle_one is None or oracle_medoid is None:
        return []
    lines = [f"- What a neural teacher must reach: the oracle plans at {oracle_one:.2f} cm with one draw and "
             f"{oracle_medoid:.2f} cm with the medoid of its draws, every path plausible (plausibility 0)."]
    for name, label in teachers.items():
        runs = teacher_runs.get(name, [])
        one, med = _mean(runs, "test/planner/ape_cm"), _mean(runs, "test/medoid/planner/ape_cm")
        plaus = _mean(runs, "test/planner/plausibility_cm")
        if one is None:
            continue
        text = f"- The {label} plans at {one:.2f} cm with one sample"
        if med is not None:
            text += f", {med:.2f} cm with the medoid of its samples"
        if plaus is not None:
            text += f"; plausibility {plaus:.2f} cm"
        lines.append(text + ".")
    return lines


def _provenance(runs: list[RunRecord], records_dir: Path) -> list[str]:
    lines = provenance_lines(command_line("spade.report"))
    lines[1:1] = ["- launch: `python -m spade.train -m +experiment=ROW seed=42,1,2,3,4` for each row below "
                  "(conf/experiment/site_*.yaml)"]
    lines.append(f"- records: {shown_path(records_dir)} ({len(runs)} runs; the page regenerates from them without "
                 "the store)")
    walls = [r.wall_s for r in runs if r.wall_s]
    if walls:
        lines.append(f"- wall time of the {len(walls)} runs: {sum(walls) / 60:.0f} min in all, "
                     f"{statistics.fmean(walls) / 60:.1f} min each on average")
    return lines


def oracle_report(tracking_uri: str, output_dir: str | Path | None, settings: Mapping[str, Any]) -> tuple[str, dict]:
    """Export the page's runs into records (when the store has them), then write ``<page>.md`` from the records."""
    labels: dict[str, str] = dict(settings.get("rows") or {})
    teachers: dict[str, str] = dict(settings.get("teachers") or {})
    against = str(settings.get("against", "site_bc_L"))
    curve = curve_series(settings.get("curve"))
    records_dir = Path(str(settings["records_dir"]))
    if store_exists(tracking_uri):
        export_records(tracking_uri, str(settings.get("experiment", "oracle")), records_dir,
                       [*labels, *teachers, *curve_rows(curve)] or None)
    runs, references = load_records(records_dir) if records_dir.is_dir() else ([], {})
    by_name: dict[str, list[RunRecord]] = {}
    for run in runs:
        by_name.setdefault(run.row, []).append(run)
    rows: dict[str, list[RunRecord]] = {name: list(by_name.get(name, [])) for name in labels}
    teacher_runs = {name: by_name[name] for name in teachers if name in by_name}
    missing = [k for k, v in rows.items() if not v]  # named rows without a finished run: shown, never dropped
    rows = {k: sorted(v, key=lambda r: (r.seed is None, r.seed or 0)) for k, v in rows.items() if v}
    tests = _tests(rows, _bases(rows, against, dict(settings.get("against_rows") or {})))
    ctests = curve_tests(curve, by_name, {(name, test["against"]): test for name, test in tests.items()})
    _correct(tests, ctests)
    title = str(settings.get("title", "Where a teacher teaches: the oracle, the site's unsketched states, the BC ceiling"))
    every_run = [r for v in rows.values() for r in v]
    floor, ceiling = _mean(every_run, "test/floor_cm"), _mean(every_run, "test/ceiling/planner/ape_cm")
    curve_lines, curve_verdict = curve_section(curve, by_name, ctests, floor, ceiling, _significant)
    parts = [f"# {title}", "", "## Verdict", "", *_verdict(rows, labels, against, tests), *curve_verdict,
             *_teacher_verdict(teachers, teacher_runs, every_run), ""]
    seeds = sorted({len(v) for v in rows.values()})
    test_size = max((len({i.get('scenario') for r in v for i in r.instances}) for v in rows.values()), default=0)
    parts += ["## Rows", "",
              f"Mean ± sd over seeds ({_seed_counts(seeds)} per row) with, for the planner's APE, the 95 % interval "
              f"of a bootstrap over the {test_size} test scenarios (all seeds pooled). The deciding figure is the "
              "planner's APE with its tail (the [metrics reference](../reference/metrics.md) says why); plausibility and "
              "commitment see the preference.", "", *_headline(rows, labels, against, tests), ""]
    for name in missing:
        parts.append(f"- not run yet: {labels.get(name, name)} (`+experiment={name}`)")
    if missing:
        parts.append("")
    tests_lines = _tests_table(rows, labels, against, tests)
    if tests_lines:
        parts += [f"## Tests against {labels.get(against, against)}", "", *tests_lines, ""]
    header = ["row", "seeds", *(catalog.label(m.split('/', 1)[1]) for m, _ in COLUMNS),
              *(("closed-loop " if m.startswith("closed_loop/") and not catalog.label(m).startswith("closed")
                 else "") + catalog.label(m.replace('test/', '')) for m in SEED_ONLY)]
    full = markdown_table(header, [[labels.get(name, name), len(runs_), *(_cell(runs_, m, c) for m, c in COLUMNS),
                                     *(_figure_cell(_values(runs_, m), m.replace("test/", "")) for m in SEED_ONLY)]
                                    for name, runs_ in rows.items()])
    parts += [*collapsed("Every figure of every row (mean ± sd over seeds, 95 % interval over scenarios)", full), ""]
    every = [r for v in rows.values() for r in v]
    parts += ["", "## Between the floor and the ceiling, beside the baselines", "",
              "The same test set for every row: these predictors learn nothing, so one run's figures hold for all.", "",
              *_reference_rows(every, references), ""]
    page = str(settings.get("page", "oracle"))
    if curve_lines:
        chart = f"{page}_curve.png"
        parts += ["## Data-size curve", "",
                  "Planner APE (cm) at each number of the site's demonstrations, mean ± sd over seeds; each series "
                  "is tested against the first at the same size by the page's rule (Welch with Holm over the page, "
                  "and the paired bootstrap over scenarios). The floor and the BC ceiling do not depend on the "
                  f"training set.{_epochs_note(by_name, curve_rows(curve))}", "", *curve_lines, "", f"![planner APE against the number of demonstrations]({chart})",
                  ""]
    teacher_lines = _teacher_rows(teachers, teacher_runs, references, every)
    if teacher_lines:
        parts += ["## The teachers as planners, beside the oracle", "",
                  "A teacher can only teach what it plans better than its student. Each teacher's samples on the same "
                  "test set, decoded by the planner (one sample with its interval over scenarios; the mean of its "
                  "samples' maps; their medoid, the minimum-Bayes-risk reading), beside the oracle as a planner.", "",
                  *teacher_lines, ""]
    shown = {id(r) for r in every}
    extra = [r for v in teacher_runs.values() for r in v] + \
        [r for name in sorted(curve_rows(curve)) for r in by_name.get(name, []) if id(r) not in shown]
    parts += ["## Provenance", "", *_provenance(every + extra, records_dir), ""]
    files: dict[str, Path] = {}
    text = "\n".join(parts)
    if output_dir is not None:
        out = Path(output_dir)
        out.mkdir(parents=True, exist_ok=True)
        files["markdown"] = out / f"{page}.md"
        files["markdown"].write_text(text + "\n")
        if curve_lines:
            files["curve"] = out / f"{page}_curve.png"
            plot_curve(curve, by_name, floor, ceiling, _best_baseline(every), files["curve"])
    return text, files


RECORDED_BATCH = 32
"""The site rows' batch (``scale=quickstart``, from ``conf/scale/cpu.yaml``), for records exported before
``cfg/data/batch_size`` was kept."""


def optimizer_steps(record: RunRecord) -> int | None:
    """The optimiser steps a run trained for: ``trainer.max_steps`` when it stopped the run, else its epochs times
    the batches of its training set (Lightning keeps the last, partial batch); None when the record cannot say."""
    def number(key: str) -> int | None:
        value = record.params.get(key)
        try:
            return int(float(value)) if value not in (None, "", "None", "null") else None
        except (TypeError, ValueError):
            return None

    steps, epochs, n = number("cfg/trainer/max_steps"), number("cfg/trainer/max_epochs"), \
        number("cfg/data/max_train_instances")
    if steps is not None and steps > 0:
        return steps
    if epochs is None or epochs < 1 or n is None:
        return None
    return epochs * math.ceil(n / (number("cfg/data/batch_size") or RECORDED_BATCH))


def _epochs_note(by_name: Mapping[str, list[RunRecord]], names: set[str]) -> str:
    """Says whether every point of the curve trained the same optimiser steps (so that only the data changes)."""
    steps = {optimizer_steps(r) for n in names for r in by_name.get(n, [])}
    if not steps or None in steps:
        return ""
    if len(steps) == 1:
        return f" Every point trains {steps.pop()} optimiser steps, so that only the data changes."
    return (f" The points train {min(steps)} to {max(steps)} optimiser steps: fewer demonstrations also mean fewer "
            "steps.")


def _best_baseline(runs: list[RunRecord]) -> tuple[str, float] | None:
    """The non-learned baseline with the lowest planner APE on the page's test set, as (label, APE)."""
    found = [(BASELINE_ROW_LABELS[b], ape) for b in BASELINE_ROW_LABELS
             if (ape := _mean(runs, f"test/baseline/{b}/planner/ape_cm")) is not None]
    return min(found, key=lambda x: x[1]) if found else None


def _seed_counts(counts: list[int]) -> str:
    if not counts:
        return "none"
    return str(counts[0]) if counts[0] == counts[-1] else f"{counts[0]} to {counts[-1]}"
