"""Run records that outlive the store: one JSON file per finished run of a page's MLflow experiment.

A results page must be regenerable and testable after the machine that held ``logs/mlflow.db`` is gone. Its runs
are exported once into files committed beside the page (``docs/results/records/<page>/``): each run's row, seed,
times, status, test and closed-loop metrics (with its baselines' and references' figures folded in) and its
per-instance planner figures (:data:`spade.metrics.path_metrics.INSTANCES_ARTIFACT`), so that intervals
over scenarios can be recomputed. The instances of the data-determined predictors (baselines, the BC ceiling and the
decoder's floor) are the same in every run on one test set: they are kept once, in ``_references.json``.

A page whose rows live in several experiments (the teacher page: its experts, students, guided rows, their drives)
keeps one such folder per experiment under its own (``docs/results/records/teacher/<experiment>/``). A page that has
no records yet (its store was lost before they existed) is kept as committed, under a notice
(:func:`with_lost_store_notice`) that says so and names the command that reruns its rows.
"""

from __future__ import annotations

import csv
import io
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from spade.metrics.path_metrics import INSTANCES_ARTIFACT
from spade.experiments.reporting.results import _search_all_runs
from spade.tracking.client import mlflow_client
from spade.utils.provenance import shown_path

__all__ = ["RunRecord", "export_records", "load_records", "has_records", "experiment_has_runs",
           "with_lost_store_notice", "keep_committed_page", "store_exists", "REFERENCES_FILE", "LOST_STORE"]

REFERENCES_FILE = "_references.json"
KEPT_PREFIXES = ("test/", "closed_loop/", "model/", "margin/")
KEPT_PARAMS = ("cfg/seed", "cfg/data/max_train", "cfg/data/batch_size", "cfg/trainer/max_epochs",
               "cfg/trainer/max_steps", "cfg/trainer/precision", "cfg/model/margin/")
"""Parameters a record keeps by default (prefixes); a page that reads more names them (``export_records(params=)``)."""
ROUND = 4
LOST_STORE = "> **Store lost:**"
"""How the lost-store notice starts (:func:`with_lost_store_notice`): one line under a page's title."""


@dataclass
class RunRecord:
    """One finished run as a page reads it."""

    row: str
    seed: int | None
    run_id: str
    start_time: int | None
    end_time: int | None
    metrics: dict[str, float]
    params: dict[str, str] = field(default_factory=dict)
    instances: list[dict[str, Any]] = field(default_factory=list)  # the model's per-instance planner figures
    tags: dict[str, str] = field(default_factory=dict)  # the tags the exporting page asked for (``tags=``)
    status: str = "FINISHED"
    commit: str | None = None
    test_sets: list[str] = field(default_factory=list)  # "name (digest)" of the run's MLflow test dataset inputs

    @property
    def wall_s(self) -> float | None:
        return (self.end_time - self.start_time) / 1000.0 if self.start_time and self.end_time else None


def _number(value: str) -> float | str:
    try:
        x = float(value)
    except ValueError:
        return value
    return round(x, ROUND) if math.isfinite(x) else x


def _instances(client: Any, run_id: str) -> list[dict[str, Any]]:
    """The run's per-instance rows (every predictor), or [] when it logged none."""
    import tempfile

    try:
        with tempfile.TemporaryDirectory() as tmp:
            path = client.download_artifacts(run_id, INSTANCES_ARTIFACT, tmp)
            text = Path(path).read_text()
    except Exception:  # noqa: BLE001 - a run from before the artifact existed: no instances
        return []
    return [{k: _number(v) for k, v in row.items()} for row in csv.DictReader(io.StringIO(text))]


def _test_sets(run: Any) -> set[str]:
    """"name (digest)" of the run's MLflow dataset inputs tagged as its test set."""
    inputs = getattr(getattr(run, "inputs", None), "dataset_inputs", None) or []
    return {f"{d.dataset.name} ({d.dataset.digest})" for d in inputs if any(t.value == "test" for t in d.tags)}


def _source_metrics(client: Any, run_id: str, names: tuple[str, ...]) -> dict[str, float]:
    try:
        metrics = client.get_run(run_id).data.metrics
    except Exception:  # noqa: BLE001 - a deleted source run: its figures are unknown
        return {}
    return {k: float(v) for k, v in metrics.items() if k in names}


def _shown(value: str) -> str:
    """A parameter as a committed record keeps it: a path relative to the project, never the writing machine's."""
    if isinstance(value, str) and value.startswith("/"):
        shown = shown_path(value)
        if shown.startswith("/"):  # outside the project (another checkout, a run folder): its file name alone
            from pathlib import PurePath

            parts = PurePath(shown).parts
            return "/".join(parts[-3:]) if "weights" in parts else parts[-1]
        return shown
    return value


def _json_safe(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _json_safe(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_json_safe(v) for v in value]
    return value


def export_records(tracking_uri: str, experiment: str, out_dir: str | Path, rows: list[str] | None = None, *,
                   scale: str | None = None, params: tuple[str, ...] = KEPT_PARAMS, tags: tuple[str, ...] = (),
                   key_tag: str | None = None, statuses: tuple[str, ...] | None = ("FINISHED",),
                   instances: bool = True, source_metrics: tuple[str, ...] = ()) -> int:
    """Write a record of every finished run of MLflow ``experiment`` (run name in ``rows`` when given) into
    ``out_dir``: ``<row>_s<seed>.json`` (the latest run of a row and seed wins) and, once, the data-determined
    predictors' instances in :data:`REFERENCES_FILE`. Returns the number of run records written.

    The keywords serve the pages that read more than the oracle page: only runs tagged with ``scale``; parameters
    by prefix (``params``) and the ``tags`` kept; ``key_tag``: the latest run per (row, seed, that tag's value),
    written ``<row>_s<seed>_<value>.json`` (a drive under an earlier condition is kept beside the latest, as
    :func:`spade.experiments.closed_loop_table.drive_cells` reads them); ``statuses``: which run states count
    (``None``: any, for a training run that failed after its test); ``instances``: whether to download the
    per-instance artifact; ``source_metrics``: metrics of the run named by its ``source_run`` tag folded in (a
    drive's trained run's ``margin/active``) where the run has none of its own."""
    client = mlflow_client(tracking_uri)
    found = client.get_experiment_by_name(experiment)
    if found is None:
        return 0
    latest: dict[tuple[str, ...], Any] = {}
    query = f"tags.scale = '{scale}'" if scale else ""
    for run in _search_all_runs(client, found.experiment_id, query):
        if run.data.tags.get("mlflow.parentRunId") or (statuses is not None and run.info.status not in statuses):
            continue
        name = run.info.run_name
        if rows is not None and name not in rows:
            continue
        key = (name, str(run.data.params.get("cfg/seed")), *((run.data.tags.get(key_tag, ""),) if key_tag else ()))
        if key not in latest or (run.info.end_time or 0) > (latest[key].info.end_time or 0):
            latest[key] = run
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    references: dict[str, list] = {}
    sources: dict[str, dict[str, float]] = {}
    for key, run in sorted(latest.items()):
        name, seed = key[0], key[1]
        rows_all = _instances(client, run.info.run_id) if instances else []
        model = [{k: v for k, v in r.items() if k != "predictor"} for r in rows_all if r.get("predictor") == "model"]
        if not references:  # the same test set in every run: the first run's copy
            for r in rows_all:
                if r.get("predictor") != "model":
                    references.setdefault(r["predictor"], []).append({k: v for k, v in r.items() if k != "predictor"})
        metrics = {k: v for k, v in run.data.metrics.items() if k.startswith(KEPT_PREFIXES)}
        source = run.data.tags.get("source_run")
        if source_metrics and source:
            if source not in sources:
                sources[source] = _source_metrics(client, source, source_metrics)
            metrics = {**sources[source], **metrics}
        record = {"row": name, "seed": int(seed) if seed not in ("None", "") else None, "run_id": run.info.run_id,
                  "start_time": run.info.start_time, "end_time": run.info.end_time,
                  "commit": run.data.tags.get("mlflow.source.git.commit") or run.data.tags.get("git_commit"),
                  "metrics": metrics, "params": {k: _shown(v) for k, v in run.data.params.items() if k.startswith(params)},
                  "instances": model}
        kept_tags = {t: run.data.tags[t] for t in tags if t in run.data.tags}
        if kept_tags:
            record["tags"] = kept_tags
        if run.info.status != "FINISHED":
            record["status"] = run.info.status
        test_sets = sorted(_test_sets(run))
        if test_sets:
            record["test_sets"] = test_sets
        stem = f"{name}_s{seed}" + (f"_{key[2] or 'none'}" if key_tag else "")
        (out / f"{stem}.json").write_text(json.dumps(_json_safe(record), indent=None, sort_keys=True) + "\n")
    if references:
        (out / REFERENCES_FILE).write_text(json.dumps(_json_safe(references), sort_keys=True) + "\n")
    return len(latest)


def load_records(records_dir: str | Path) -> tuple[list[RunRecord], dict[str, list[dict[str, Any]]]]:
    """The run records of ``records_dir`` and the data-determined predictors' instances (``{}`` without them)."""
    root = Path(records_dir)
    runs = []
    for path in sorted(root.glob("*.json")):
        if path.name == REFERENCES_FILE:
            continue
        raw = json.loads(path.read_text())
        runs.append(RunRecord(raw["row"], raw.get("seed"), raw.get("run_id", ""), raw.get("start_time"),
                              raw.get("end_time"), {k: float(v) for k, v in raw["metrics"].items() if v is not None},
                              raw.get("params") or {}, raw.get("instances") or [], raw.get("tags") or {},
                              raw.get("status") or "FINISHED", raw.get("commit"), raw.get("test_sets") or []))
    refs_path = root / REFERENCES_FILE
    references = json.loads(refs_path.read_text()) if refs_path.is_file() else {}
    return runs, references


def store_exists(tracking_uri: str) -> bool:
    """Whether the store holds anything to export (a SQLite file that exists, or a server URI): a page never
    creates a store by reading a lost one."""
    if tracking_uri.startswith("sqlite:///"):
        return Path(tracking_uri[len("sqlite:///"):]).is_file()
    return tracking_uri.startswith(("http://", "https://"))


def experiment_has_runs(tracking_uri: str, experiment: str) -> bool:
    """Whether the store exists and holds a run of MLflow ``experiment`` (never creating the store)."""
    if not store_exists(tracking_uri):
        return False
    client = mlflow_client(tracking_uri)
    found = client.get_experiment_by_name(experiment)
    return found is not None and bool(client.search_runs([found.experiment_id], max_results=1))


def has_records(records_dir: str | Path) -> bool:
    """Whether ``records_dir`` (or a folder in it: a page of several experiments) holds a run record."""
    root = Path(records_dir)
    return root.is_dir() and any(p.name != REFERENCES_FILE for p in root.rglob("*.json"))


def with_lost_store_notice(text: str, command: str, records_dir: str | Path | None) -> str:
    """``text`` (a committed page) with one line under its title (``command``: Markdown, its commands in code spans) saying that its runs' store was lost, which
    command reruns its rows (and writes their records into ``records_dir``), and that the figures below are the lost
    store's. An earlier notice is replaced, so the page carries one however often it is kept."""
    records = "" if records_dir is None else (f" (which also writes their run records into "
                                              f"`{shown_path(records_dir)}`, from which the page then regenerates "
                                              "without a store)")
    notice = (f"{LOST_STORE} the MLflow store that held this page's runs was lost, so the figures below are from "
              f"that store and cannot be regenerated until its rows are rerun: {command}{records}.")
    lines = [line for line in text.splitlines() if not line.startswith(LOST_STORE)]
    while len(lines) > 2 and lines[1] == "" and lines[2] == "":  # the blank line the removed notice left
        del lines[1]
    if lines and lines[0].startswith("# "):
        lines[1:1] = ["", notice]
    else:
        lines[0:0] = [notice, ""]
    return "\n".join(lines).rstrip("\n") + "\n"


def keep_committed_page(committed: str | Path | None, command: str, records_dir: str | Path | None,
                        output_dir: str | Path | None, name: str) -> tuple[str, dict[str, Path]] | None:
    """A page without records: its committed copy under the lost-store notice (:func:`with_lost_store_notice`),
    written as ``output_dir/name`` too; ``None`` when there is no committed copy (the page is then built from what
    there is, which says that nothing has run)."""
    if committed is None or not Path(committed).is_file():
        return None
    text = with_lost_store_notice(Path(committed).read_text(), command, records_dir)
    files: dict[str, Path] = {}
    if output_dir is not None:
        out = Path(output_dir)
        out.mkdir(parents=True, exist_ok=True)
        files["markdown"] = out / name
        files["markdown"].write_text(text)
    return text, files
