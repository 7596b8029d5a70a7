"""The teacher page: every expert as a planner beside the students it is meant to teach, on one test set.

A diffusion expert can only teach a student where it plans better than the student: the paper's conditional expert
plans at 1.42 cm APE where its medium BC student is at 3.48. This page (``python -m spade.report table=teacher``)
reads, from MLflow, each expert run's test as a planner (:meth:`ExpertModule.test_step`: one sample, the mean of K
samples' maps, the spread of two samples against the generator's) and each student row's test (mean +/- sd over its
seeds), beside the classical baselines of the same test set, and says for each expert whether it meets the teacher's
targets against the student of its own marker encoding (a single sample's plausibility at most 1.0 cm, its planner
APE at most 0.8x the student's, its spread within 20 % of the generator's). Each expert is compared with its
student by a one-sample t-test of the student's per-seed values against the expert's figure (an expert of one seed
has no spread of its own: the test asks whether the expert lies outside the student's seed-to-seed variation), with
Holm's correction over the page.

Rows are named in a page of the ``conf/teacher/`` group (``experts``, ``students``, ``guided``: MLflow experiment and
run name): ``teacher=main`` (the default) writes ``teacher.md``, ``teacher=width`` the width lever's
``teacher_width.md``; each page's ``page`` setting names its files.

The page reads run records (:mod:`spade.experiments.run_records`), one folder per MLflow experiment under its
``records_dir`` (the drives' in ``closed_loop/``, the experts' training runs in ``_training/``), exported from the
store first when the store exists: once its rows are rerun, the page regenerates from the committed records without
the store. A page without records keeps its committed copy under the lost-store notice.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from spade.experiments.reporting.stats import holm, mean_sd, one_sample, significance, welch
from spade.experiments.run_records import RunRecord
from spade.metrics import catalog
from spade.metrics.catalog import BASELINE_ROW_LABELS
from spade.utils.markdown import collapsed, markdown_table
from spade.experiments.closed_loop_table import CLOSED_LOOP_TABLE, drive_cells, export_drives
from spade.experiments.run_records import export_records, has_records, keep_committed_page, load_records, store_exists
from spade.utils.provenance import command_line, provenance_lines, shown_path

__all__ = ["TEACHER_TABLE", "teacher_files", "teacher_report"]

DEFAULT_TITLE = "The teacher: each expert as a planner beside its student"

TEACHER_TABLE = "teacher"


def teacher_files(stem: str | None = None) -> tuple[str, str]:
    """The files a teacher page writes into ``output_dir``: ``<page>.md`` and ``<page>.csv`` (``teacher`` unless the
    page's ``page`` setting names it otherwise)."""
    stem = str(stem or TEACHER_TABLE)
    return f"{stem}.md", f"{stem}.csv"



COLUMNS: tuple[tuple[str, str, str], ...] = tuple((catalog.label(n), n, catalog.figure(n).fmt) for n in catalog.TEACHER)
"""(label, metric after ``test/`` [and the prefix of the reading], format) of the page's columns."""
BASELINES = BASELINE_ROW_LABELS
TARGET_PLAUSIBILITY_CM = 1.0
TARGET_APE_RATIO = 0.8
TARGET_SPREAD = 0.2
TESTED = ("planner/ape_cm", "planner/plausibility_cm")
PARAMS = ("cfg/seed", "cfg/data/test_dir", "cfg/data/encoding", "cfg/model/preset", "cfg/trainer/max_epochs",
          "cfg/model/ema_decay", "cfg/model/test_samples")
"""The parameters the page's records keep (its rows' settings and the experts' training records)."""
TRAINING = "_training"
"""The folder of ``records_dir`` that holds the experts' training runs (any status: one may fail after its test)."""
def rerun_command(page: str | None) -> str:
    """What reruns a teacher page's rows and rewrites it, for the lost-store notice (``teacher_width``: the
    ``teacher=width`` page)."""
    stem = str(page or TEACHER_TABLE)
    option = "" if stem == TEACHER_TABLE else f" teacher={stem.removeprefix(TEACHER_TABLE + '_')}"
    return (f"the commands of its row in the [results index](README.md), then `python -m spade.report table=teacher"
            f"{option} scale=quickstart output_dir=docs/results`")
Records = dict[tuple[str, str], list[RunRecord]]
"""Run records by (MLflow experiment, run name)."""


@dataclass
class Row:
    """One row of the page: its label, kind (expert or student), marker encoding and its runs' metrics."""

    label: str
    kind: str
    encoding: str
    runs: list[dict[str, float]] = field(default_factory=list)
    seeds: list[str] = field(default_factory=list)
    params: dict[str, str] = field(default_factory=dict)
    seconds: float = 0.0
    test_sets: set[str] = field(default_factory=set)  # "name (digest)" of the runs' MLflow test dataset inputs

    def values(self, key: str) -> list[float]:
        return [m[key] for m in self.runs if key in m and not math.isnan(m[key])]

    def mean(self, key: str) -> float | None:
        v = self.values(key)
        return statistics.fmean(v) if v else None


def _cell(row: Row, key: str, fmt: str) -> str:
    """The row's mean ± sd over its seeds; the value alone when its seeds agree."""
    values = row.values(key)
    return mean_sd(values if len(set(values)) > 1 else values[:1], fmt)


def _rows(records: Records, sources: Sequence[Mapping[str, str]], kind: str) -> list[Row]:
    rows = []
    for source in sources:
        runs = records.get((str(source["table"]), str(source["row"])), [])
        if not runs:
            rows.append(Row(str(source.get("label", source["row"])), kind, "?"))
            continue
        runs = sorted(runs, key=lambda r: str(r.seed))
        encoding = {r.tags.get("encoding") or r.params.get("cfg/data/encoding", "binary") for r in runs}
        rows.append(Row(
            label=str(source.get("label", source["row"])), kind=kind, encoding=",".join(sorted(encoding)),
            runs=[dict(r.metrics) for r in runs], seeds=[str(r.seed if r.seed is not None else "?") for r in runs],
            params={k: v for k, v in runs[0].params.items() if k in ("cfg/data/test_dir", "cfg/model/preset",
                    "cfg/trainer/max_epochs", "cfg/model/ema_decay", "cfg/model/test_samples")},
            seconds=sum(r.wall_s or 0.0 for r in runs), test_sets=set().union(*(r.test_sets for r in runs))))
    return rows


def _sources(settings: Mapping[str, Any]) -> dict[str, set[str]]:
    """The run names the page reads, by MLflow experiment: experts, students, guided rows and their twins (each
    also as ``<row>_real`` unless the item says ``real: false``)."""
    wanted: dict[str, set[str]] = {}
    for source in [*(settings.get("experts") or []), *(settings.get("students") or [])]:
        wanted.setdefault(str(source["table"]), set()).add(str(source["row"]))
    for item in settings.get("guided") or []:
        against = dict(item.get("against") or {})
        for suffix in ("",) if item.get("real", True) is False else ("", "_real"):
            wanted.setdefault(str(item["table"]), set()).add(f"{item['row']}{suffix}")
            wanted.setdefault(str(against.get("table", "")), set()).add(f"{against.get('row', '')}{suffix}")
    return wanted


def _drive_names(settings: Mapping[str, Any]) -> list[str]:
    """The drives the guidance section shows: each guided row's and twin's clean drives of both scenario sets."""
    rows = {str(r) for item in settings.get("guided") or [] for r in (item["row"], (item.get("against") or {}).get("row"))
            if r}
    return sorted(f"{row}__{dataset}__clean" for row in rows for dataset in ("heldout", "real"))


def export_teacher_records(tracking_uri: str, records_dir: Path, settings: Mapping[str, Any],
                           scale: str | None) -> int:
    """The page's runs as records in ``records_dir``: ``<experiment>/`` per experiment of its rows, ``closed_loop/``
    for its guided rows' drives, ``_training/<experiment>/`` for the experts' training runs. Returns the count."""
    count = 0
    for experiment, names in sorted(_sources(settings).items()):
        count += export_records(tracking_uri, experiment, records_dir / experiment, sorted(names), scale=scale,
                                params=PARAMS, tags=("encoding", "scale"))
    if settings.get("guided"):
        count += export_drives(tracking_uri, records_dir / CLOSED_LOOP_TABLE, scale, _drive_names(settings))
    for source in settings.get("experts") or []:
        trained = source.get("trained_by")
        if trained:
            count += export_records(tracking_uri, str(trained["table"]), records_dir / TRAINING / str(trained["table"]),
                                    [str(trained["row"])], params=PARAMS, statuses=None, instances=False)
    return count


def _load(records_dir: Path) -> Records:
    """Every experiment folder's records of ``records_dir``, by (experiment, run name)."""
    out: Records = {}
    if not records_dir.is_dir():
        return out
    for folder in sorted(p for p in records_dir.iterdir() if p.is_dir() and p.name != TRAINING):
        for run in load_records(folder)[0]:
            out.setdefault((folder.name, run.row), []).append(run)
    return out


def _parameters(row: Row) -> str:
    """The row's network size (``model/params``, logged by every training and evaluation run), in millions."""
    value = row.mean("model/params")
    return "n/a" if value is None else f"{value / 1e6:.2f} M"


CLOSED_LOOP_COLUMNS: tuple[tuple[str, str, str], ...] = tuple(
    (catalog.label(n), n, catalog.figure(n).fmt) for n in ("closed_loop/success_rate", "closed_loop/ape_cm"))
"""(label, metric, format) of a guided row's closed loop: its drives of the same scenario set, clean condition."""
GUIDED_TESTED = tuple((n, catalog.figure(n).fmt) for n in ("planner/ape_cm", "planner/over_20cm_rate",
                                                             "planner/plausibility_cm", "planner/commit_rate"))


def _guided(records: Records, guided: Sequence[Mapping[str, Any]],
            drives: Mapping[tuple[str, str, str], Any] | None = None, seconds: dict[str, float] | None = None
            ) -> tuple[list[str], list[tuple[str, str, str, float, float, float | None]]]:
    """The guided students against their BC twins, on the held-out map and (runs ``<row>_real``) the unseen real
    maps (unless the item says ``real: false``): a table of the deciding figures, the closed loop where the rows were
    driven (``drives``: :func:`spade.experiments.closed_loop_table.drive_cells`, the clean condition of the same
    scenario set) and the margin's activity, and Welch tests (what, figure, format, guided mean, twin mean, p).
    ``seconds`` receives each counted row's and drive's wall time (by name, so a twin shared by rows counts once)."""
    body: list[list[Any]] = []
    tests = []
    for item in guided:
        against = dict(item.get("against") or {})
        for where, suffix, dataset in (("held-out map", "", "heldout"), ("unseen real maps", "_real", "real")):
            if suffix and item.get("real", True) is False:  # a row that is never tested on the real maps
                continue
            row = _rows(records, [{"table": item["table"], "row": f"{item['row']}{suffix}",
                                   "label": item.get("label", item["row"])}], "student")[0]
            twin = _rows(records, [{"table": against.get("table", ""), "row": f"{against.get('row', '')}{suffix}",
                                    "label": against.get("label") or f"BC twin ({against.get('row', '?')})"}],
                         "student")[0]
            driven = {}
            for r, source in ((row, item["row"]), (twin, against.get("row", ""))):
                cell = (drives or {}).get((str(source), dataset, "clean"))
                if seconds is not None:
                    seconds[f"{source}{suffix}"] = r.seconds
                    if cell is not None:
                        seconds[f"{source}__{dataset}__clean"] = cell.seconds
                driven[id(r)] = [m for _, m in sorted(cell.seeds.items())] if cell is not None else []
                loop = Row(r.label, r.kind, r.encoding, runs=driven[id(r)])
                loop_cells = [_cell(loop, key, fmt) if loop.runs else "not driven" for _, key, fmt in CLOSED_LOOP_COLUMNS]
                if not r.runs:
                    body.append([r.label, where, 0, *(["missing"] * len(COLUMNS)), *loop_cells, "missing"])
                    continue
                active = _cell(r, "margin/active", ".0%") if r is row else "-"
                body.append([r.label, where, len(r.runs), *(_cell(r, "test/" + key, fmt) for _, key, fmt in COLUMNS),
                             *loop_cells, active])
            for key, fmt in GUIDED_TESTED:
                a, b = row.values("test/" + key), twin.values("test/" + key)
                if a and b:
                    tests.append((f"{row.label} vs {twin.label}, {where}", key, fmt, statistics.fmean(a),
                                  statistics.fmean(b), welch(a, b)[0]))
            for _, key, fmt in CLOSED_LOOP_COLUMNS:
                a = [m[key] for m in driven[id(row)] if key in m and math.isfinite(m[key])]
                b = [m[key] for m in driven[id(twin)] if key in m and math.isfinite(m[key])]
                if a and b:
                    tests.append((f"{row.label} vs {twin.label}, {where}", key, fmt, statistics.fmean(a),
                                  statistics.fmean(b), welch(a, b)[0]))
    header = ["student", "test set", "seeds", *(c[0] for c in COLUMNS), *(c[0] for c in CLOSED_LOOP_COLUMNS),
              "margin active (last epoch)"]
    return markdown_table(header, body, "llr" + "r" * (len(header) - 3)), tests


def _training_lines(training: Records, experts: Sequence[Mapping[str, Any]]) -> list[str]:
    """One line per expert whose entry names its training run (``trained_by: {table, row}``): its status, epochs,
    steps and wall time, from its record (a run that failed after its training still carries them)."""
    lines = []
    for source in experts:
        trained = source.get("trained_by")
        if not trained:
            continue
        runs = training.get((str(trained["table"]), str(trained["row"])), [])
        if not runs:
            lines.append(f"- {source.get('label', source['row'])}: its training run `{trained['table']}/{trained['row']}` "
                         "is not in this store")
            continue
        run = max(runs, key=lambda r: r.start_time or 0)
        minutes = ((run.end_time or run.start_time or 0) - (run.start_time or 0)) / 60000.0
        lines.append(f"- {source.get('label', source['row'])}: run `{trained['table']}/{trained['row']}` "
                     f"({run.run_id[:8]}), status {run.status}"
                     + (f" ({trained['note']})" if trained.get("note") else "")
                     + f", {minutes:.0f} min; params as trained: "
                     + ", ".join(f"{k.split('/', 1)[1]}={v}" for k, v in sorted(run.params.items())
                                 if k in ("cfg/model/preset", "cfg/trainer/max_epochs", "cfg/model/ema_decay",
                                          "cfg/data/encoding", "cfg/seed")))
    return lines


def _p(p: float | None) -> str:
    return "n/a" if p is None else f"{p:.3g}"


def _significant_first(table: list[str], what: str) -> list[str]:
    """A tests table (header, rule, rows ending in their verdict) as the significant rows, then the rest collapsed
    (pymdownx.details: the docs site shows them closed)."""
    header, rows = table[:2], table[2:]
    significant = [r for r in rows if r.endswith("| significant |")]
    rest = [r for r in rows if r not in significant]
    out = [*header, *significant, ""] if significant else [f"No {what[:-1]} is significant.", ""]
    if rest:
        out += [*collapsed(f"The other {len(rest)} {what} (not significant, or no test)", [*header, *rest]), ""]
    return out


def summary(expert_tests: Sequence[tuple[str, float, float, float | None]],
            guided_tests: Sequence[tuple[str, float, float, float | None]]) -> list[str]:
    """The page's finding in two sentences, by the deciding figure (planner APE): the experts against their
    students ((what, expert, student mean, Holm p)), then the guided students against their BC twins ((what,
    guided, twin, Holm p)). Its first sentence is the page's one-line finding in the results index."""
    out = []
    if expert_tests:
        better = [t for t in expert_tests if t[1] < t[2] and t[3] is not None and t[3] < 0.05]
        worse = [t for t in expert_tests if t[1] > t[2] and t[3] is not None and t[3] < 0.05]
        closest = min(expert_tests, key=lambda t: t[1] - t[2])
        out.append((f"{len(better)} of {len(expert_tests)} experts plan better than their student by the planner's APE"
                    if better else f"No expert plans better than its student by the planner's APE")
                   + f" (the closest, {closest[0].split(' vs ')[0]}, at {closest[1]:.2f} cm against {closest[2]:.2f} "
                   f"cm){f'; {len(worse)} plan significantly worse' if worse else ''}.")
    if guided_tests:
        told = [t for t in guided_tests if t[3] is not None and t[3] < 0.05]
        out.append((f"{len(told)} of {len(guided_tests)} guided students are told apart from their BC twins by the "
                    "planner's APE: " + "; ".join(f"{t[0]} ({t[1]:.2f} vs {t[2]:.2f} cm)" for t in told) if told else
                    f"Guidance from the teacher does not change the planner's APE: none of the {len(guided_tests)} "
                    "guided students is told apart from its BC twin")
                   + " (Welch over seeds, Holm's correction over the page).")
    if not out:
        return ["No comparison can be tested yet."]
    return [" ".join(out)]


def teacher_report(tracking_uri: str, output_dir: str | Path | None, settings: Mapping[str, Any],
                   scale: str | None = None) -> tuple[str, dict[str, Path]]:
    """Render the teacher page from its run records (module docstring), exported from the store first when it
    exists (into ``settings["records_dir"]``; a temporary folder without one); with ``output_dir`` also write
    ``teacher.md`` and ``teacher.csv`` there. Without records the committed page (``settings["committed"]``) is
    kept under the lost-store notice. Returns the markdown and the files written."""
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        records_dir = Path(str(settings["records_dir"])) if settings.get("records_dir") else Path(tmp)
        if store_exists(str(tracking_uri)):  # a lost store is never created empty: the records alone are read
            export_teacher_records(str(tracking_uri), records_dir, settings, scale)
        if not has_records(records_dir):
            kept = keep_committed_page(settings.get("committed"), rerun_command(settings.get("page")), records_dir,
                                       output_dir, teacher_files(settings.get("page"))[0])
            if kept is not None:
                return kept
        records = _load(records_dir)
        training = _load(records_dir / TRAINING)
        drive_records = load_records(records_dir / CLOSED_LOOP_TABLE)[0] \
            if (records_dir / CLOSED_LOOP_TABLE).is_dir() else []
        record_count = sum(len(v) for v in records.values())
    experts = _rows(records, list(settings.get("experts") or []), "expert")
    students = _rows(records, list(settings.get("students") or []), "student")
    guided = list(settings.get("guided") or [])  # a lever page of experts alone names none
    header = ("| predictor | markers | seeds | " + " | ".join(c[0] for c in COLUMNS)
              + " | spread / generator's | ms per sample | parameters |")
    lines = [header, "|---|---|---:|" + "---:|" * (len(COLUMNS) + 3)]
    csv_rows: list[list[Any]] = []
    for row in experts:
        if not row.runs:
            lines.append(f"| {row.label} | ? | 0 | " + " | ".join("missing" for _ in range(len(COLUMNS) + 3)) + " |")
            continue
        k = row.params.get("cfg/model/test_samples")
        readings = [("one sample", "test/"), (f"mean of {k or 'K'} samples' maps", "test/mean_map/")]
        if row.values("test/medoid/planner/ape_cm"):  # the minimum-Bayes-risk reading, where the test logged it
            readings.append((f"medoid of {k or 'K'} samples' paths", "test/medoid/"))
        for reading, prefix in readings:
            extra = [_cell(row, "test/planner/spread_ratio", ".2f"), _cell(row, "test/seconds_per_sample", ".3f"),
                     _parameters(row)]
            if prefix != "test/":
                extra = ["", "", ""]
            elif extra[1] != "n/a":
                extra[1] = f"{row.mean('test/seconds_per_sample') * 1000:.0f}"
            lines.append(f"| {row.label}, {reading} | {row.encoding} | {len(row.runs)} | "
                         + " | ".join(_cell(row, prefix + key, fmt) for _, key, fmt in COLUMNS)
                         + f" | {' | '.join(extra)} |")
            csv_rows.append([row.label, reading, row.encoding, len(row.runs),
                             *[row.mean(prefix + key) for _, key, _ in COLUMNS]])
    for row in students:
        lines.append(f"| {row.label} | {row.encoding} | {len(row.runs)} | "
                     + " | ".join(_cell(row, "test/" + key, fmt) for _, key, fmt in COLUMNS) + f" | | | {_parameters(row)} |")
        csv_rows.append([row.label, "student", row.encoding, len(row.runs),
                         *[row.mean("test/" + key) for _, key, _ in COLUMNS]])
    # the baselines read the map, start and goal, never the markers: one row each, from the first student that has them
    for row in [s for s in students if any(s.values(f"test/baseline/{n}/planner/ape_cm") for n in BASELINES)][:1]:
        for name, label in BASELINES.items():
            if row.values(f"test/baseline/{name}/planner/ape_cm"):
                lines.append(f"| {label} | - | - | "
                             + " | ".join(_cell(row, f"test/baseline/{name}/{key}", fmt) for _, key, fmt in COLUMNS)
                             + " | | | |")

    # targets and tests: each expert against the student of its encoding
    tests: list[tuple[str, str, float, list[float]]] = []
    target_lines = []
    for expert in experts:
        if not expert.runs:
            continue
        student = next((s for s in students if s.encoding == expert.encoding and s.runs), None)
        if student is None:
            target_lines.append(f"- {expert.label}: no student row on {expert.encoding} markers to compare with")
            continue
        plaus = expert.mean("test/planner/plausibility_cm")
        ape, student_ape = expert.mean("test/planner/ape_cm"), student.mean("test/planner/ape_cm")
        ratio = expert.mean("test/planner/spread_ratio")
        generator = expert.mean("test/generator_spread_cm")
        parts = []
        if plaus is not None:
            parts.append(f"plausibility {plaus:.2f} cm (target ≤ {TARGET_PLAUSIBILITY_CM:.1f}: "
                         f"{'met' if plaus <= TARGET_PLAUSIBILITY_CM else 'not met'})")
        if ape is not None and student_ape is not None:
            goal = TARGET_APE_RATIO * student_ape
            parts.append(f"planner APE {ape:.2f} cm = {ape / student_ape:.2f}x the student's {student_ape:.2f} "
                         f"(target ≤ {TARGET_APE_RATIO}x = {goal:.2f} cm: {'met' if ape <= goal else 'not met'})")
        if ratio is not None:
            parts.append(f"spread {ratio:.2f}x the generator's (target within ±{TARGET_SPREAD:.0%}: "
                         f"{'met' if abs(ratio - 1) <= TARGET_SPREAD else 'not met'})")
        if generator is not None and student_ape is not None:
            reach = "below" if generator <= TARGET_APE_RATIO * student_ape else "above"
            parts.append(f"the generator's spread is {generator:.2f} cm, {reach} the APE target: a calibrated sampler's "
                         "single sample lies about that far from the demonstration, so "
                         + ("a calibrated single sample can meet the APE target" if reach == "below" else
                            "a single sample that is also as wide as the operator's choices cannot meet the APE target "
                            "(only a mean map or a committed, narrower sampler could)"))
        target_lines.append(f"- {expert.label} against {student.label}: " + "; ".join(parts))
        for key in TESTED:
            value = expert.mean("test/" + key)
            if value is not None:
                tests.append((f"{expert.label} vs {student.label}", key, value, student.values("test/" + key)))
    guided_seconds: dict[str, float] = {}
    guided_lines, guided_tests = _guided(records, guided, drive_cells(drive_records, scale), guided_seconds)
    ps = [one_sample(values, value) for _, _, value, values in tests]
    adjusted = holm(ps + [t[5] for t in guided_tests])
    guided_holm = adjusted[len(ps):]
    test_rows = []
    verdicts = []
    expert_ape: list[tuple[str, float, float, float | None]] = []  # (what, expert, student, Holm p): the summary's
    guided_ape: list[tuple[str, float, float, float | None]] = []
    for (what, key, value, values), p, ph in zip(tests, ps, adjusted):
        mean = statistics.fmean(values) if values else float("nan")
        sig = significance(ph)
        test_rows.append([what, key, f"{value:.2f}", f"{mean:.2f}", _p(p), _p(ph), sig])
        if key == "planner/ape_cm":
            word = "better" if value < mean else "worse"
            expert_ape.append((what, value, mean, ph))
            verdicts.append(f"- {what}: the expert plans {word} than its student by planner APE ({value:.2f} vs "
                            f"{mean:.2f} cm), {sig}" + (f" (Holm p {ph:.3g})" if ph is not None else ""))

    test_lines = markdown_table(["comparison", "figure", "expert", "student (mean of seeds)", "p", "p (Holm)",
                                 "verdict"], test_rows, "llrrrrl")
    guided_rows = []
    for (what, key, fmt, a, b, p), ph in zip(guided_tests, guided_holm):
        sig = significance(ph)
        guided_rows.append([what, key, format(a, fmt), format(b, fmt), _p(p), _p(ph), sig])
        if key == "planner/ape_cm":
            word = "better" if a < b else "worse" if a > b else "the same"
            guided_ape.append((what, a, b, ph))
            verdicts.append(f"- {what}: the first plans {word} by planner APE ({a:.2f} vs {b:.2f} cm), {sig}"
                            + (f" (Holm p {ph:.3g})" if ph is not None else ""))
    guided_test_lines = markdown_table(["comparison", "figure", "guided", "BC twin", "Welch p", "p (Holm)",
                                        "verdict"], guided_rows, "llrrrrl")
    test_sets = sorted(set().union(*(r.test_sets for r in experts + students)))
    training_lines = _training_lines(training, list(settings.get("experts") or []))
    seconds = sum(r.seconds for r in experts)
    guidance_part = [
        "Guidance from the teacher: each guided student against its BC twin (the same student, data and test without "
        "the margin), mean ± sd over seeds; Welch's two-sided t-test over the per-seed values, Holm's correction "
        "over the page together with the tests above. A guided row whose margin was not active in its last epoch "
        "trained as BC. The closed-loop columns are each row's drives of the same scenario set, clean condition "
        "(`python -m spade.closed_loop`, one drive per seed; the closed-loop page has the rest): *not driven* where "
        "none was.",
        "",
        *guided_lines,
        "",
        *(_significant_first(guided_test_lines, "guided tests") if guided_tests else []),
    ] if guided else []
    provenance = provenance_lines(command_line("spade.report"))
    parts = [
        f"# {settings.get('title') or DEFAULT_TITLE}",
        "",
        *summary(expert_ape, guided_ape),
        "",
        "The figure that decides is the planner's APE with its tail (the [metrics reference]"
        "(../reference/metrics.md#which-figure-decides) states it for open and closed loop).",
        "",
        "Each expert's test samples every test instance K times (DDIM) and decodes each sample with the planner a "
        "robot would run (`spade.metrics.decoding`): *one sample* is what a robot asking the expert once would "
        "drive, *mean of K samples' maps* what K samples buy. Students: mean ± sd over their seeds. The figure that "
        f"decides is the planner's APE and its tail ({catalog.label('over_20cm_rate')}), then plausibility (the APE "
        "to the nearest plausible "
        "demonstration) and commitment; a teacher is worth its cost where it plans better than its student.",
        "",
        f"Test set (MLflow dataset input, name and digest): {', '.join(test_sets) or 'not recorded'}"
        + (f", scale {scale}" if scale else "") + "."
        + (" **The rows were tested on different sets: compare only rows on the same one.**" if len(test_sets) > 1
           else ""),
        "",
        *lines,
        "",
        "Targets (each expert against the student on the same markers):",
        "",
        *(target_lines or ["- no expert row has finished runs"]),
        "",
        "Tests: a two-sided one-sample t-test of the student's per-seed values against the expert's figure (the "
        "expert rows have one seed: the test asks whether the expert lies outside the student's seed-to-seed "
        "variation, not whether another expert seed would), Holm's correction over the page, alpha 0.05.",
        "",
        *(_significant_first(test_lines, "expert tests") if tests else ["No comparison can be tested yet.", ""]),
        *guidance_part,
        "Each comparison by the planner's APE:",
        "",
        *(verdicts or ["- no comparison yet"]),
        "",
        *(["Training records of the experts (their MLflow runs):", "", *training_lines, ""] if training_lines
          else []),
        "Provenance:",
        "",
        *provenance[:1],
        f"- records: {shown_path(records_dir)} ({record_count} runs; the page regenerates from them without the "
        "store)" if settings.get("records_dir") else "- records: none kept (no records_dir)",
        *provenance[1:],
        f"- wall time of the expert test runs counted: {seconds / 60:.0f} min",
        *([f"- wall time of the guided rows, their BC twins and their drives counted: "
           f"{sum(guided_seconds.values()) / 3600:.1f} h (their training, tests and re-tests, one process each)"]
          if guided else []),
        f"- MLflow store {shown_path(str(tracking_uri))}; rows: "
        + ", ".join(f"`{s['table']}/{s['row']}`" for s in [*(settings.get('experts') or []),
                                                          *(settings.get('students') or []),
                                                          *guided]),
    ]
    text = "\n".join(parts) + "\n"
    files: dict[str, Path] = {}
    if output_dir is not None:
        import csv

        out = Path(output_dir)
        out.mkdir(parents=True, exist_ok=True)
        md_name, csv_name = teacher_files(settings.get("page"))
        files["markdown"], files["csv"] = out / md_name, out / csv_name
        files["markdown"].write_text(text)
        with files["csv"].open("w", newline="") as fh:
            writer = csv.writer(fh)
            writer.writerow(["predictor", "reading", "markers", "seeds", *[key for _, key, _ in COLUMNS]])
            writer.writerows(csv_rows)
    return text, files
