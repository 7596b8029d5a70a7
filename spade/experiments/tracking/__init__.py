"""What every run records in MLflow besides Lightning's metrics, and how a person opens it in the MLflow UI.

One module per job:

- :mod:`~spade.experiments.tracking.links`: the MLflow UI's address, the URLs of runs, runs tables and
  artifacts, and the ``mlflow ui`` command (:func:`ui_lines`, printed at the end of training and by
  ``spade.report``);
- :mod:`~spade.experiments.tracking.experiment_tags`: an experiment's metadata: tagged as model training (which
  MLflow 3.17's UI no longer reads to choose an experiment's first page: its sidebar switch does, see there), its
  description (the paper table it reproduces and how to regenerate it) and SPADE's runs view (the Dataset and
  metric columns, runs sorted by name: each row's run followed by its predictors);
- :mod:`~spade.experiments.tracking.dataset_inputs`: a run's datasets as MLflow dataset inputs (name, digest =
  the dataset's fingerprint, source = its directory, context training / validation / test, the manifest's key
  facts as the profile);
- :mod:`~spade.experiments.tracking.descriptions`: a run's description (row, approach, prerequisites linked to
  their runs, test figures next to the classical baselines and the untrained model) and the descriptions of the
  models it registers;
- :mod:`~spade.experiments.tracking.logged_model`: a student run's best checkpoint as the run's own MLflow Model
  ``model`` (ONNX, ``runs:/RUN_ID/model``; not registered);
- :mod:`~spade.experiments.tracking.params`: a run's parameters, the settings that describe the method (no
  paths, Hydra or logger internals, sweep bookkeeping or copies; the whole config is ``config/train.yaml``);
- :mod:`~spade.experiments.tracking.predictors`: the classical baselines and the untrained model as child runs of
  the model's run, with its metric names (the runs table compares them row by row);
- :mod:`~spade.experiments.tracking.run_report`: the run's report, ``report/run_report.md`` and
  ``report/test_figures.csv``;
- :mod:`~spade.experiments.tracking.runs`: an MLflow run from start to end: opened in its tagged experiment,
  its parameters and ``config/train.yaml``, the FID extractor's identity and its process recorded, its
  checkpoints, student model, training-progress picture, inputs, description, predictors and report logged when
  it finishes, marked KILLED / FAILED when it does not, and stale RUNNING runs of a row marked KILLED;
- :mod:`~spade.experiments.tracking.summary`: the closing lines of ``spade.train``;
- :mod:`~spade.experiments.tracking.report`: ``spade.report``'s table published in MLflow.

The names below are re-exported for the callers that import them from the package (imported on first use).
"""

from __future__ import annotations

import importlib
from typing import Any

# name -> module: imported on first use (PEP 562), so that a torch- and Lightning-free module of this package
# (predictors, links, run_report) can be imported without the ones that need Lightning (runs, logger)
_EXPORTS = {
    "DatasetUse": "dataset_inputs", "dataset_fingerprint": "dataset_inputs", "dataset_uses": "dataset_inputs",
    "log_dataset_inputs": "dataset_inputs",
    "figures_table": "descriptions", "prerequisite_uses": "descriptions", "run_description": "descriptions",
    "KIND_TAG": "experiment_tags", "NOTE_TAG": "experiment_tags", "VIEW_TAG": "experiment_tags",
    "ui_lines": "links",
    "run_params": "params",
    "PREDICTOR_TAG": "predictors", "TOP_LEVEL_FILTER": "predictors", "is_predictor_run": "predictors",
    "log_predictor_runs": "predictors", "with_predictor_figures": "predictors",
    "publish_report": "report",
    "log_run_report": "run_report",
    "bind_experiment": "runs", "finish_evaluation": "runs", "finish_run": "runs", "start_run_logging": "runs",
    "run_summary": "summary",
}


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{module}"), name)
    globals()[name] = value
    return value


__all__ = [
    "KIND_TAG",
    "NOTE_TAG",
    "PREDICTOR_TAG",
    "TOP_LEVEL_FILTER",
    "VIEW_TAG",
    "DatasetUse",
    "bind_experiment",
    "dataset_fingerprint",
    "dataset_uses",
    "figures_table",
    "finish_evaluation",
    "finish_run",
    "is_predictor_run",
    "log_dataset_inputs",
    "log_predictor_runs",
    "log_run_report",
    "prerequisite_uses",
    "publish_report",
    "run_description",
    "run_params",
    "run_summary",
    "start_run_logging",
    "ui_lines",
]
