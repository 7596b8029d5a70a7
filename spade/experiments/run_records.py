"""Run records that outlive the store: one JSON file per finished run of a page's MLflow experiment.

A results page must be regenerable and testable after the machine that held ``logs/mlflow.db`` is gone. Its runs
are exported once into files committed beside the page (``docs/results/records/<page>/``): each run's row, seed,
times, status, test and closed-loop metrics (with its baselines' and references' figures folded in) and its
per-instance planner figures (:data:`spade.metrics.path_metrics.INSTANCES_ARTIFACT`), so that intervals
over scenarios can be recomputed. The instances of the data-determined predictors (baselines, the BC ceiling and the
decoder's floor) are the same in every run on one test set: they are kept once, in ``_references.json``.
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

__all__ = ["RunRecord", "export_records", "load_records", "REFERENCES_FILE"]

REFERENCES_FILE = "_references.json"
KEPT_PREFIXES = ("test/", "closed_loop/", "model/", "margin/")
ROUND = 4


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


def _shown(value: str) -> str:
    """A parameter as a committed record keeps it: a path relative to the project, never the writing machine's."""
    if isinstance(value, str) and value.startswith("/"):
        from spade.utils.provenance import shown_path

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


def export_records(tracking_uri: str, experiment: str, out_dir: str | Path, rows: list[str] | None = None) -> int:
    """Write a record of every finished run of MLflow ``experiment`` (run name in ``rows`` when given) into
    ``out_dir``: ``<row>_s<seed>.json`` (the latest run of a row and seed wins) and, once, the data-determined
    predictors' instances in :data:`REFERENCES_FILE`. Returns the number of run records written."""
    from spade.experiments.reporting.results import _search_all_runs
    from spade.tracking.client import mlflow_client

    client = mlflow_client(tracking_uri)
    found = client.get_experiment_by_name(experiment)
    if found is None:
        return 0
    latest: dict[tuple[str, str], Any] = {}
    for run in _search_all_runs(client, found.experiment_id, ""):
        if run.data.tags.get("mlflow.parentRunId") or run.info.status != "FINISHED":
            continue
        name = run.info.run_name
        if rows is not None and name not in rows:
            continue
        key = (name, str(run.data.params.get("cfg/seed")))
        if key not in latest or (run.info.end_time or 0) > (latest[key].info.end_time or 0):
            latest[key] = run
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    references: dict[str, list] = {}
    for (name, seed), run in sorted(latest.items()):
        rows_all = _instances(client, run.info.run_id)
        model = [{k: v for k, v in r.items() if k != "predictor"} for r in rows_all if r.get("predictor") == "model"]
        if not references:  # the same test set in every run: the first run's copy
            for r in rows_all:
                if r.get("predictor") != "model":
                    references.setdefault(r["predictor"], []).append({k: v for k, v in r.items() if k != "predictor"})
        metrics = {k: v for k, v in run.data.metrics.items() if k.startswith(KEPT_PREFIXES)}
        params = {k: _shown(v) for k, v in run.data.params.items() if k.startswith(("cfg/seed", "cfg/data/max_train",
                                                                                  "cfg/trainer/max_epochs",
                                                                                  "cfg/model/margin/"))}
        record = {"row": name, "seed": int(seed) if seed not in ("None", "") else None, "run_id": run.info.run_id,
                  "start_time": run.info.start_time, "end_time": run.info.end_time,
                  "commit": run.data.tags.get("mlflow.source.git.commit") or run.data.tags.get("git_commit"),
                  "metrics": metrics, "params": params, "instances": model}
        (out / f"{name}_s{seed}.json").write_text(json.dumps(_json_safe(record), indent=None, sort_keys=True) + "\n")
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
                              raw.get("params") or {}, raw.get("instances") or []))
    refs_path = root / REFERENCES_FILE
    references = json.loads(refs_path.read_text()) if refs_path.is_file() else {}
    return runs, references
