"""The closed-loop table: trained students driven through whole scenarios, with seeds, beside the classical planners.

Launch (``python -m spade.closed_loop``, conf/closed_loop.yaml): for every finished run (one per seed) of the source
rows (by default the guidance table's BC and Cond-DBC rows at equal size, and the quickstart's student), its best
checkpoint is driven by ``spade.evaluate closed_loop=true`` on each scenario set (the held-out map, the unseen real
maps) under each condition (clean; perturbed: localisation noise and an initial offset), each drive a run of its own
in the MLflow experiment ``closed_loop`` named ``<row>__<dataset>__<condition>``, carrying its source run and seed.
A drive is keyed by its full settings (:func:`drive_settings`: the source run and seed, the scenario set, the
condition's effective ``drive`` options with the planner's, open loop or not, the code's commit), recorded with it
(tags ``drive_key``, ``condition_key``, ``drive_settings``): a drive that already finished with the same settings is
not run again (the launch resumes), and a changed setting runs it again. The page shows, in each cell, only the
drives of its latest settings, so it never keeps old numbers under a changed condition.

Report (``python -m spade.report table=closed_loop``): per dataset and condition, every row's closed-loop figures as
mean +/- sd over its seeds beside the baselines driven in the same runs; tests (Welch's between rows, paired between
a row and a baseline over the seeds) with Holm's correction over the page; and whether the open-loop ranking
(planner APE) and the closed-loop ranking (closed-loop APE) agree.
"""

from __future__ import annotations

import json
import logging
import math
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from spade.experiments.reporting.stats import holm, mean_sd, paired, significance, welch
from spade.metrics import catalog
from spade.metrics.catalog import BASELINE_LABELS
from spade.utils.markdown import collapsed, markdown_table
from spade.utils.provenance import provenance_lines
from spade.data.fingerprint import fingerprint
from spade.experiments.evaluation import evaluate
from spade.experiments.run_records import export_records, has_records, keep_committed_page, load_records, store_exists
from spade.tracking.client import ensure_store, mlflow_client
from spade.tracking.predictors import with_predictor_figures
from spade.utils.config import compose_config
from spade.utils.provenance import command_line, commit, shown_path

__all__ = ["CLOSED_LOOP_TABLE", "closed_loop_report", "launch"]

log = logging.getLogger(__name__)

CLOSED_LOOP_TABLE = "closed_loop"
"""The MLflow experiment (``tags.table``) of the drives, and the ``spade.report`` table name."""
TITLE = "Closed loop: students driven through whole scenarios, beside the classical planners"

FIGURES: tuple[tuple[str, str, str, bool | None], ...] = tuple(
    (catalog.label(n, qualified=False), n.removeprefix("closed_loop/"), catalog.figure(n).fmt,
     catalog.lower_is_better(n)) for n in catalog.CLOSED_LOOP)
"""Figures of a drive (:data:`spade.metrics.catalog.CLOSED_LOOP`): (label, metric suffix after
``closed_loop/[prefix]``, format, lower is better)."""
REFERENCES = {"baseline/shortest/": BASELINE_LABELS["shortest"], "baseline/heading/": BASELINE_LABELS["heading"],
              "followed/": "demonstration followed", "demonstration/": "demonstration replayed"}
MARGIN_ACTIVE = "margin/active"
"""A guided row's share of active margins in its last training epoch (its source run's; BC has none)."""
OPEN_LOOP = "planner/ape_cm"
"""The open-loop figure a drive's source run logged (its test), beside the closed-loop ones."""
TESTED = ("ape_cm", "success_rate", "plausibility_cm", "mode_switches")
"""The figures the page tests: the deciding one (closed-loop APE) first."""


# -- launch ------------------------------------------------------------------------------------------------------
def _best_checkpoint(client: Any, run: Any, cache: Path) -> Path | None:
    for folder in ("checkpoints/best", "checkpoints/last"):
        files = [a for a in client.list_artifacts(run.info.run_id, folder) if a.path.endswith(".ckpt")]
        if files:
            dst = cache / run.info.run_id
            dst.mkdir(parents=True, exist_ok=True)
            return Path(client.download_artifacts(run.info.run_id, files[0].path, str(dst)))
    return None


def source_runs(client: Any, table: str, row: str, scale: str | None) -> list[Any]:
    """The latest finished run of each seed of ``row`` in ``table``'s MLflow experiment (at ``scale``)."""
    experiment = client.get_experiment_by_name(table)
    if experiment is None:
        return []
    query = f"attributes.run_name = '{row}' and attributes.status = 'FINISHED'"
    if scale:
        query += f" and tags.scale = '{scale}'"
    runs = client.search_runs([experiment.experiment_id], query, order_by=["attributes.end_time DESC"])
    by_seed: dict[str, Any] = {}
    for run in runs:
        if run.data.tags.get("mlflow.parentRunId"):
            continue  # a baseline's child run
        by_seed.setdefault(run.data.params.get("cfg/seed", run.info.run_id), run)
    return with_predictor_figures(client, list(by_seed.values()))  # its baselines' figures, from its child runs


DRIVE_KEY, CONDITION_KEY, DRIVE_SETTINGS = "drive_key", "condition_key", "drive_settings"
"""Tags of a drive: the fingerprint of its full settings, of its settings less the source run and seed (shared by
a cell's seeds), and the settings themselves (JSON)."""
OUTPUT_ONLY = ("pictures", "mcap", "mcap_episodes")
"""``drive`` options that change what a drive writes beside its figures, not the figures: outside its key."""


def drive_settings(cfg: Any, dataset: str, data: str, condition: str) -> dict[str, Any]:
    """What a drive's figures depend on, from its composed ``spade.evaluate`` config ``cfg``: the scenario set
    (``dataset``, its ``data`` config and scale, ``drive.scenarios``), the ``condition`` with every effective ``drive``
    option (noise, offsets, follower, planner options, baselines, ...; :data:`OUTPUT_ONLY` left out), whether the
    open-loop test runs, and the code (:func:`spade.utils.provenance.commit`, else the package version)."""
    from importlib.metadata import PackageNotFoundError, version

    from omegaconf import OmegaConf

    try:
        code = commit() or f"spade {version('spade')}"
    except PackageNotFoundError:  # neither a checkout nor an install: the code is unknown, and recorded so
        code = "unknown"

    drive = OmegaConf.to_container(cfg.drive, resolve=True)
    return {"dataset": dataset, "data": data,
            "scale": str(OmegaConf.select(cfg, "scale.name", default="")), "condition": condition,
            "drive": {k: v for k, v in dict(drive).items() if k not in OUTPUT_ONLY},  # type: ignore[arg-type]
            "open_loop": bool(cfg.get("open_loop")), "code": code}


def drive_keys(settings: Mapping[str, Any], source_run: str, seed: int) -> tuple[str, str]:
    """(drive key, condition key): fingerprints of ``settings`` with and without the source run and seed."""
    return fingerprint({**settings, "source_run": source_run, "seed": int(seed)}, 16), fingerprint(settings, 16)


def _finished_drives(client: Any) -> set[str]:
    """The drive keys of the finished drives (a drive from before keys has none: it is run again)."""
    experiment = client.get_experiment_by_name(CLOSED_LOOP_TABLE)
    if experiment is None:
        return set()
    runs = client.search_runs([experiment.experiment_id], "attributes.status = 'FINISHED'", max_results=5000)
    return {r.data.tags[DRIVE_KEY] for r in runs if r.data.tags.get(DRIVE_KEY)}


def launch(cfg: Any) -> list[dict[str, Any]]:
    """Drive every (source run, dataset, condition) not yet driven (module docstring); returns what ran."""
    from omegaconf import OmegaConf, open_dict

    ensure_store(str(cfg.tracking_uri))  # a fresh store created whole, under its lock, before the first search
    client = mlflow_client(str(cfg.tracking_uri))
    done = _finished_drives(client)
    cache = Path(str(cfg.cache_dir))
    ran = []
    for source in cfg.sources:
        table, row = str(source.table), str(source.row)
        runs = source_runs(client, table, row, cfg.scale.name)
        if not runs:
            log.warning("closed loop: no finished run of %s in %s at scale %s: launch it first", row, table,
                        cfg.scale.name)
        for run in runs:
            seed = int(run.data.params.get("cfg/seed", cfg.seed))
            ckpt = None
            for dataset, data_cfg in cfg.datasets.items():
                for condition, settings in cfg.conditions.items():
                    name = f"{row}__{dataset}__{condition}"
                    overrides = [f"data={data_cfg.data}", f"scale={cfg.scale.name}",
                                 f"run_name={name}", f"tags.table={CLOSED_LOOP_TABLE}", f"tags.row={name}",
                                 f"+tags.source_run={run.info.run_id}", f"+tags.source_row={row}",
                                 f"+tags.dataset={dataset}", f"+tags.condition={condition}", f"seed={seed}",
                                 f"source_seed={seed}", "closed_loop=true", f"open_loop={condition == 'clean'}",
                                 f"drive.scenarios={data_cfg.scenarios}", "trainer.enable_progress_bar=false",
                                 f"paths.output_dir={cfg.paths.output_dir}/{name}/{seed}",
                                 f"paths.mlflow_tracking_uri={cfg.tracking_uri}"]
                    overrides += [f"drive.{k}={v}" for k, v in OmegaConf.to_container(settings).items()]
                    wanted = drive_settings(compose_config("evaluate", overrides), dataset, str(data_cfg.data),
                                            condition)
                    key, condition_key = drive_keys(wanted, run.info.run_id, seed)
                    if key in done:
                        continue
                    ckpt = ckpt or _best_checkpoint(client, run, cache)
                    if ckpt is None:
                        log.warning("closed loop: run %s of %s has no checkpoint artifact; skipped", run.info.run_id,
                                    row)
                        break
                    drive_cfg = compose_config("evaluate", [*overrides, f"ckpt_path={ckpt}"])
                    with open_dict(drive_cfg):  # set, not typed on a command line: no quoting of the JSON
                        drive_cfg.tags.update({DRIVE_KEY: key, CONDITION_KEY: condition_key,
                                               DRIVE_SETTINGS: json.dumps(wanted, sort_keys=True)})
                    t0 = time.perf_counter()
                    metrics = evaluate(drive_cfg)
                    ran.append({"run": name, "seed": seed, "seconds": time.perf_counter() - t0,
                                "success_rate": metrics.get("closed_loop/success_rate")})
                    print(f"closed loop: {name} seed {seed}: success {metrics.get('closed_loop/success_rate'):.0%}, "
                          f"APE {metrics.get('closed_loop/ape_cm'):.2f} cm ({time.perf_counter() - t0:.0f} s)",
                          flush=True)
    return ran


# -- report ------------------------------------------------------------------------------------------------------
@dataclass
class Cell:
    """The drives of one (row, dataset, condition): one metrics dict per seed."""

    row: str
    dataset: str
    condition: str
    seeds: dict[int, dict[str, float]] = field(default_factory=dict)
    seconds: float = 0.0

    def values(self, key: str) -> list[float]:
        return [m[key] for _, m in sorted(self.seeds.items()) if key in m and math.isfinite(m[key])]


DRIVE_TAGS = ("source_row", "source_run", "dataset", "condition", CONDITION_KEY, "scale")
"""The tags a drive's run record keeps (:mod:`spade.experiments.run_records`): where it came from and what ran."""


def export_drives(tracking_uri: str, records_dir: str | Path, scale: str | None = None,
                  rows: list[str] | None = None) -> int:
    """The finished drives of the ``closed_loop`` experiment (run names ``rows`` when given) as run records in
    ``records_dir``: one per (cell, seed, condition key), each with its trained run's ``margin/active``."""
    return export_records(tracking_uri, CLOSED_LOOP_TABLE, records_dir, rows, scale=scale, tags=DRIVE_TAGS,
                          key_tag=CONDITION_KEY, instances=False, source_metrics=(MARGIN_ACTIVE,))


def drive_cells(runs: list[Any], scale: str | None = None) -> dict[tuple[str, str, str], Cell]:
    """The drives' run records (:func:`export_drives`) as cells: the latest drive per seed of each (row, dataset,
    condition), only under the cell's latest settings (its latest drive's condition key)."""
    cells: dict[tuple[str, str, str], Cell] = {}
    settings: dict[tuple[str, str, str], str | None] = {}
    for run in sorted(runs, key=lambda r: -(r.end_time or 0)):
        tags = run.tags
        if "source_row" not in tags or (scale and tags.get("scale", scale) != scale):
            continue
        key = (tags["source_row"], tags.get("dataset", "?"), tags.get("condition", "?"))
        cell = cells.setdefault(key, Cell(*key))
        if settings.setdefault(key, tags.get(CONDITION_KEY)) != tags.get(CONDITION_KEY):
            continue  # a drive under the condition's earlier settings: never shown beside the latest
        seed = int(run.seed) if run.seed is not None else -1
        if seed in cell.seeds:
            continue  # an older drive of the same seed
        cell.seeds[seed] = dict(run.metrics)
        if run.wall_s:
            cell.seconds += run.wall_s
    return cells


def fetch_drives(tracking_uri: str, scale: str | None = None) -> dict[tuple[str, str, str], Cell]:
    """The finished drives of the ``closed_loop`` experiment, the latest run per seed of each cell (read through
    their run records, as a page reads them: :func:`export_drives`, :func:`drive_cells`)."""
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        export_drives(tracking_uri, tmp, scale)
        return drive_cells(load_records(tmp)[0], scale)


def _seeds_cell(values: list[float], fmt: str) -> str:
    """A cell over seeds; a share's spread in percentage points."""
    return mean_sd(values, fmt, (lambda sd: f"{sd * 100:.0f} pt") if fmt.endswith("%") else None)


@dataclass
class Test:
    what: str
    figure: str
    a: float
    b: float
    p: float | None
    kind: str
    p_holm: float | None = None


def _ranking(cells: list[Cell], key: str) -> list[str]:
    means = [(float(np.mean(c.values(key))), c.row) for c in cells if c.values(key)]
    return [row for _, row in sorted(means)]


RERUN_COMMAND = ("`python -m spade.closed_loop`, then `python -m spade.report table=closed_loop scale=quickstart "
                 "output_dir=docs/results`")
"""What reruns the closed-loop page's rows (its drives) and rewrites it, for the lost-store notice."""


def closed_loop_report(tracking_uri: str, output_dir: str | Path | None, scale: str | None = None,
                       rows: list[str] | None = None, labels: Mapping[str, str] | None = None,
                       records_dir: str | Path | None = None, committed: str | Path | None = None
                       ) -> tuple[str, dict]:
    """Render the closed-loop page (markdown) from the drives' run records, exported from the ``closed_loop``
    experiment first when the store has it (into ``records_dir``; a temporary folder without one); with
    ``output_dir`` also write ``closed_loop.md`` and ``closed_loop.csv``. Without records, the ``committed`` page is
    kept under the lost-store notice (:func:`spade.experiments.run_records.keep_committed_page`). Returns the text
    and the files written."""
    import tempfile

    labels = dict(labels or {})
    with tempfile.TemporaryDirectory() as tmp:
        records = Path(records_dir) if records_dir is not None else Path(tmp)
        if store_exists(tracking_uri):  # a lost store is never created empty: the records alone are read
            export_drives(tracking_uri, records, scale)
        if not has_records(records):
            kept = keep_committed_page(committed, RERUN_COMMAND, records, output_dir, "closed_loop.md")
            if kept is not None:
                return kept
        drives = load_records(records)[0] if records.is_dir() else []
    cells = drive_cells(drives, scale)
    order = rows or sorted({k[0] for k in cells})
    groups = sorted({(k[1], k[2]) for k in cells}, key=lambda g: (g[0] != "heldout", g[0], g[1] != "clean", g[1]))
    parts = [f"# {TITLE}", ""]
    if not cells:
        parts += [f"No finished drive in the MLflow experiment `{CLOSED_LOOP_TABLE}` of {shown_path(tracking_uri)}"
                  + (f" at scale {scale}" if scale else "") + ": launch them with `python -m spade.closed_loop`."]
        return "\n".join(parts), {}
    parts += [
        "Every scenario of a test set driven from its demonstration's start pose to its goal: the planner plans from "
        "the robot's pose as the deployed node does, a pure-pursuit controller follows each plan, the robot replans "
        "every 0.5 m driven (and when 0.5 m off its plan); an episode ends at the goal (10 cm), on a lethal cell of "
        "the map's inflated costmap (a collision), with no plan, or at its time budget (`spade/closedloop`, "
        "`conf/drive/default.yaml`). Each figure is the mean ± sd over the seeds of a row (one training run per "
        "seed; the baselines are driven in the same runs, so their spread is the noise's). APE is the executed "
        "path against the whole demonstration; plausibility against the nearest of the demonstration and its "
        "alternatives; commits: within 5 cm of one of them; mode switches: how often the plan's turn side or radius "
        "band changed between replans, per scenario.", "",
        "A guided row is guidance only where its margin acted: the last column is the share of its training "
        "instances whose margin was active in the last epoch (its training run's `margin/active`); near 0, the row "
        "trained as BC did at the end.", "",
        ]
    tests: list[Test] = []
    csv_rows = []
    for dataset, condition in groups:
        here = [cells[(r, dataset, condition)] for r in order if (r, dataset, condition) in cells]
        if not here:
            continue
        n_scen = int(max((m.get("closed_loop/episodes", 0) for c in here for m in c.seeds.values()), default=0))
        parts += [f"### {dataset}, {condition} ({n_scen} scenarios)", ""]
        header = ["planner", "runs", *[f[0] for f in FIGURES], f"open-loop {catalog.label(OPEN_LOOP)}",
                  catalog.label(MARGIN_ACTIVE)]
        body = []
        for c in here:
            cols = [labels.get(c.row, c.row), str(len(c.seeds))]
            cols += [_seeds_cell(c.values(f"closed_loop/{key}"), fmt) for _, key, fmt, _ in FIGURES]
            cols.append(_seeds_cell(c.values(catalog.mlflow_key(OPEN_LOOP)), catalog.figure(OPEN_LOOP).fmt))
            cols.append(_seeds_cell(c.values(MARGIN_ACTIVE), ".1%") if c.values(MARGIN_ACTIVE) else "no margin")
            body.append(cols)
            csv_rows.append([dataset, condition, c.row, len(c.seeds)]
                            + [float(np.mean(c.values(f"closed_loop/{k}"))) if c.values(f"closed_loop/{k}") else ""
                               for _, k, _, _ in FIGURES])
        pooled = Cell("baselines", dataset, condition)  # every drive of the group: the baselines ran in each
        for i, m in enumerate(m for c in here for m in c.seeds.values()):
            pooled.seeds[i] = m
        for prefix, name in REFERENCES.items():
            if not pooled.values(f"closed_loop/{prefix}success_rate"):
                continue
            cols = [f"*{name}*", str(len(pooled.seeds))]
            cols += [_seeds_cell(pooled.values(f"closed_loop/{prefix}{key}"), fmt) for _, key, fmt, _ in FIGURES]
            body.append([*cols, "", ""])
        parts += [*markdown_table(header, body), ""]
        # tests: every pair of rows (Welch), every row against the Nav2-like and heading baselines (paired by seed)
        for i, a in enumerate(here):
            for b in here[i + 1:]:
                for key in TESTED:
                    va, vb = a.values(f"closed_loop/{key}"), b.values(f"closed_loop/{key}")
                    if va and vb:
                        tests.append(Test(f"{dataset}, {condition}: {labels.get(a.row, a.row)} vs "
                                          f"{labels.get(b.row, b.row)}", key, float(np.mean(va)), float(np.mean(vb)),
                                          welch(va, vb)[0], "Welch"))
            for prefix in ("baseline/shortest/", "baseline/heading/"):
                for key in ("ape_cm", "success_rate"):
                    pairs = [(m[f"closed_loop/{key}"], m[f"closed_loop/{prefix}{key}"]) for m in a.seeds.values()
                             if f"closed_loop/{prefix}{key}" in m and f"closed_loop/{key}" in m]
                    if pairs:
                        va, vb = [p[0] for p in pairs], [p[1] for p in pairs]
                        tests.append(Test(f"{dataset}, {condition}: {labels.get(a.row, a.row)} vs "
                                          f"{REFERENCES[prefix]}", key, float(np.mean(va)), float(np.mean(vb)),
                                          paired(va, vb), "paired t"))
        open_rank = _ranking(here, catalog.mlflow_key(OPEN_LOOP))
        closed_rank = _ranking(here, "closed_loop/ape_cm")
        if len(open_rank) > 1 and condition == "clean":
            agree = open_rank == closed_rank
            parts += [f"Ranking by open-loop planner APE: {' < '.join(labels.get(r, r) for r in open_rank)}; by "
                      f"closed-loop APE: {' < '.join(labels.get(r, r) for r in closed_rank)}: "
                      + ("they agree." if agree else "**they disagree**."), ""]
    for t, adjusted in zip(tests, holm([t.p for t in tests])):  # one family: every test of the page
        t.p_holm = adjusted
    significant = [t for t in tests if t.p_holm is not None and t.p_holm < 0.05]
    if tests:
        parts += [f"## Tests ({len(significant)} of {len(tests)} significant)", "",
                  "Two-sided; Holm's correction over every test of this page; significant: adjusted p < 0.05; n/a: "
                  "fewer than 2 seeds or no spread. The significant tests first, the rest collapsed below.", "",
                  *(_test_table(significant) if significant else ["No test is significant."]), ""]
        rest = [t for t in tests if t not in significant]
        if rest:
            parts += [*collapsed(f"The other {len(rest)} tests (not significant, or no test)", _test_table(rest)),
                      ""]
    parts += ["## Every comparison in words", "", *[f"- {line}" for line in verdict_lines(tests, labels)], ""]
    head = [f"# {TITLE}", "", *summary(tests, labels), "",
            "Which figure decides in closed loop: the success rate, then the closed-loop APE (the [metrics "
            "reference](../reference/metrics.md#which-figure-decides) states it for open and closed loop).", ""]
    parts = head + parts[2:]
    seconds = sum(c.seconds for c in cells.values())
    driving = sum(m.get("closed_loop/seconds", 0.0) for c in cells.values() for m in c.seeds.values())
    parts += ["## Provenance", "", *provenance_lines(command_line("spade.report"), "python -m spade.closed_loop"),
              f"- wall time of the {sum(len(c.seeds) for c in cells.values())} drives counted: {driving / 60:.1f} min "
              f"driving (every planner, closed_loop/seconds); their MLflow runs {seconds / 60:.0f} min (the clean "
              "drives' open-loop tests included)",
              f"- MLflow experiment `{CLOSED_LOOP_TABLE}` in {shown_path(tracking_uri)}"
              + (f", scale {scale}" if scale else ""),
              *([f"- records: {shown_path(records_dir)} ({len(drives)} drives; the page regenerates from them "
                 "without the store)"] if records_dir is not None else [])]
    files: dict[str, Path] = {}
    text = "\n".join(parts) + "\n"
    if output_dir is not None:
        out = Path(output_dir)
        out.mkdir(parents=True, exist_ok=True)
        files["markdown"] = out / "closed_loop.md"
        files["csv"] = out / "closed_loop.csv"
        files["markdown"].write_text(text)
        import csv

        with files["csv"].open("w", newline="") as fh:
            writer = csv.writer(fh)
            writer.writerow(["dataset", "condition", "row", "seeds", *[k for _, k, _, _ in FIGURES]])
            writer.writerows(csv_rows)
    return text, files


def _test_table(tests: list[Test]) -> list[str]:
    body = []
    for t in tests:
        fmt = next(f for _, k, f, _ in FIGURES if k == t.figure)
        body.append([t.what, t.figure, format(t.a, fmt), format(t.b, fmt), t.kind,
                     "n/a" if t.p_holm is None else f"{t.p_holm:.3g}", significance(t.p_holm)])
    return markdown_table(["comparison", "figure", "A", "B", "test", "p (Holm)", "verdict"], body, "llrrlrl")


def _decisions(tests: list[Test]) -> list[tuple[str, str, str, dict[str, Test], str | None]]:
    """Each comparison the seeds can test: (group, A, B, its tests by figure, the winner or ``None``), decided by
    the success rate first, then the closed-loop APE, each by its Holm-adjusted p."""
    by_pair: dict[str, dict[str, Test]] = {}
    for t in tests:
        if t.figure in ("success_rate", "ape_cm"):
            by_pair.setdefault(t.what, {})[t.figure] = t
    out = []
    for what, figs in by_pair.items():
        if all(t.p_holm is None for t in figs.values()):
            continue
        group, pair = what.split(": ", 1)
        a, b = pair.split(" vs ")
        winner = None
        for t, higher_better in ((figs.get("success_rate"), True), (figs.get("ape_cm"), False)):
            if t is not None and t.p_holm is not None and t.p_holm < 0.05 and t.a != t.b:
                winner = a if (t.a > t.b) == higher_better else b
                break
        out.append((group, a, b, figs, winner))
    return out


def summary(tests: list[Test], labels: Mapping[str, str]) -> list[str]:
    """The page's finding in two or three sentences: what the tests between students and against the classical
    planners establish (its first sentence is the page's one-line finding in the results index)."""
    decisions = _decisions(tests)
    planners = set(REFERENCES.values())
    between = [d for d in decisions if d[2] not in planners]
    against = [d for d in decisions if d[2] in planners]
    told = [d for d in between if d[4] is not None]
    if not decisions:
        return ["No comparison can be tested yet (every row has fewer than two seeds)."]
    first = (f"Driven in closed loop, no student is told apart from another ({len(between)} comparisons by success, "
             "then closed-loop APE, Holm's correction over the page)." if not told else
             f"Driven in closed loop, {len(told)} of {len(between)} comparisons between students are told apart: "
             + "; ".join(f"{d[4]} wins against {d[2] if d[4] == d[1] else d[1]} ({d[0]})" for d in told) + ".")
    wins = [d for d in against if d[4] == d[1]]
    losses = [d for d in against if d[4] == d[2]]
    second = (f"Against the classical planners the students win {len(wins)} of {len(against)} comparisons"
              + (f" and lose {len(losses)}" if losses else " and lose none")
              + "; the rest are not told apart."
              + (f" The wins: {'; '.join(sorted({f'{d[0]}, against the {d[2]}' for d in wins}))}." if wins else ""))
    return [first + " " + second] if against else [first]


def verdict_lines(tests: list[Test], labels: Mapping[str, str]) -> list[str]:
    """The tests in words, one line per comparison that the seeds can test: the deciding figure (success) first,
    then the closed-loop APE, each with its Holm-adjusted verdict; comparisons without a test (a row of one seed)
    are left to the tables."""
    lines = []
    for group, a, b, figs, winner in _decisions(tests):
        words = []
        for figure, name, fmt in (("success_rate", "success", ".1%"), ("ape_cm", "APE", ".2f")):
            t = figs.get(figure)
            if t is None:
                continue
            unit = "" if figure == "success_rate" else " cm"
            order = "equal" if t.a == t.b else ("higher" if t.a > t.b else "lower")
            sig = significance(t.p_holm)
            words.append(f"{name} {format(t.a, fmt)}{unit} vs {format(t.b, fmt)}{unit} ({order}, {sig})")
        decided = "no difference established" if winner is None else f"{a} {'wins' if winner == a else 'loses'}"
        lines.append(f"{group}: {a} against {b}: {'; '.join(words)}: **{decided}**")
    return lines
