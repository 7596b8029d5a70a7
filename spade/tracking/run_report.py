"""A run's deliverable report, logged as the artifacts ``report/run_report.md`` and ``report/test_figures.csv``.

The markdown is the run's description (row, approach, data, prerequisites, guidance, the command that regenerates
it) under a title, with the test figures of the model next to each classical baseline and the untrained model and
the line saying what each figure means (:func:`~spade.tracking.descriptions.figures_table`). The CSV
holds the same figures at full precision, one line per predictor (the model's role, ``baseline-<name>``,
``untrained``: the names of :mod:`~spade.tracking.predictors`), one column per MLflow metric.
"""

from __future__ import annotations

import csv
import math
import tempfile
from pathlib import Path
from typing import Any

from spade.tracking.descriptions import FIGURES
from spade.tracking.predictors import predictors

REPORT_DIR = "report"
MARKDOWN = "run_report.md"
CSV = "test_figures.csv"
# the CSV's columns: the description's figures, then the rest a reader compares
CSV_KEYS = tuple(f"test/{k}" for k in (*FIGURES, "planner/low_confidence_rate", "hd19_rate", "score_cm",
                                      "instances", "seconds_per_sample"))


def figure_lines(metrics: dict[str, float], role: str = "model") -> list[dict[str, Any]]:
    """One dict per predictor (``predictor``, ``label``, then :data:`CSV_KEYS`): the model's own test figures (when
    it logged any), each baseline's and the untrained model's, under the model's metric names (a baseline driven in
    closed loop only, with no test figure, has no line)."""
    own = {k: float(metrics[k]) for k in CSV_KEYS if k in metrics}
    lines = [(role, "this model", own)] if own else []
    lines += [(p.name, p.label, p.metrics) for p in predictors(metrics) if any(k in p.metrics for k in CSV_KEYS)]
    return [{"predictor": name, "label": label, **{k: figures.get(k) for k in CSV_KEYS}}
            for name, label, figures in lines]


def _cell(value: Any) -> str:
    if value is None:
        return ""
    return "nan" if isinstance(value, float) and math.isnan(value) else repr(float(value))


def write_run_report(out_dir: str | Path, run_name: str, description: str, metrics: dict[str, float],
                     role: str = "model") -> dict[str, Path]:
    """Write ``run_report.md`` and (when the run has test figures) ``test_figures.csv`` under ``out_dir``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    files = {"markdown": out / MARKDOWN}
    lines = figure_lines(metrics, role)
    text = f"# Run `{run_name}`\n\n{description}\n"
    if lines:
        files["csv"] = out / CSV
        with open(files["csv"], "w", newline="") as fh:
            writer = csv.writer(fh)
            writer.writerow(["predictor", "label", *CSV_KEYS])
            for line in lines:
                writer.writerow([line["predictor"], line["label"], *(_cell(line[k]) for k in CSV_KEYS)])
        text += (f"\nThe figures at full precision, one line per predictor: `{CSV}` (beside this file). Each "
                 "predictor is also a child run of this run in the MLflow runs table, with the same metric names.\n")
    files["markdown"].write_text(text)
    return files


def log_run_report(client: Any, run_id: str, run_name: str, description: str, metrics: dict[str, float],
                   role: str = "model") -> list[str]:
    """Log the run's report into its ``report/`` artifacts; returns the artifact paths logged."""
    with tempfile.TemporaryDirectory(prefix="spade-run-report-") as tmp:
        files = write_run_report(tmp, run_name, description, metrics, role)
        for path in files.values():
            client.log_artifact(run_id, str(path), artifact_path=REPORT_DIR)
    return [f"{REPORT_DIR}/{p.name}" for p in files.values()]
