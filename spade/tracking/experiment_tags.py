"""An MLflow experiment's metadata: tagged as model training, described (the paper table it reproduces), SPADE's view.

The experiment (one per paper table, quickstart, smoke, sweep or evaluation) is tagged as model-training work
(``mlflow.experimentKind=custom_model_development``: the UI's "Machine learning" kind; MLflow 3 UIs before 3.17
chose an experiment's first page by it),
carries a description (``mlflow.note.content``: the paper table it reproduces and how to regenerate it) and stores
the runs-table view that shows the rounded test figures (the deciding figure first) and the Dataset, one line per
run sorted by run name, so that a row's run is followed by its baselines and untrained model (:data:`VIEW_TAG`,
:func:`runs_view_state`).

What the tag does not do: MLflow 3.17's UI no longer reads ``mlflow.experimentKind`` to choose an experiment's
first page. With its workflow-based navigation (on in every 3.17 build), the kind follows the sidebar's
"GenAI / Model training" switch: the URL's ``workflowType`` parameter, else the browser's local storage
(``mlflow.workflowType_v1``, written only when a person flips the switch), else GenAI. A fresh browser profile that
clicks an experiment in the experiments list therefore lands on the GenAI overview whatever the tags say. Every link
SPADE prints carries ``workflowType=machine_learning`` (:mod:`~spade.tracking.links`), and
:func:`~spade.tracking.links.ui_lines` says to flip the switch once (the browser remembers it).
"""

from __future__ import annotations

import json
from typing import Any

from omegaconf import DictConfig

from spade.tracking.figure_tags import FIGURES as FIGURE_TAGS, tag_key
from spade.tracking.links import VIEW_KEY
from spade.tracking.tables import METRICS, TABLES

KIND_TAG = "mlflow.experimentKind"
KIND_TRAINING = "custom_model_development"  # the MLflow UI's "model training" experiments
NOTE_TAG = "mlflow.note.content"  # an experiment's or a run's description in the MLflow UI
VIEW_TAG = f"mlflow.sharedViewState.{VIEW_KEY}"  # the runs-table view that ?viewStateShareKey=<VIEW_KEY> opens


RUN_NAME_KEY = "tags.`mlflow.runName`"  # the UI's sort key of the Run Name column
# a figure column's width: its header's characters (at least a value's, "108.94 cm"), and the sort and menu icons
CHAR_PX, HEADER_PX, VALUE_CHARS = 7, 40, 10


def runs_view_state() -> str:
    """The runs table as SPADE shows it: the test figures rounded, the deciding figure first (the planner's APE,
    its tail, plausibility, commitment, then the paper's figures and the parameter count: run tags of
    :mod:`~spade.tracking.figure_tags`, each column wide enough for its header), then Dataset; the runs sorted by
    name.

    Sorted by name, a row's run (``quickstart``) is followed by its predictors' child runs
    (``quickstart/baseline-heading``, ..., ``quickstart/untrained``: :mod:`~spade.tracking.predictors`),
    each a line of its own with the same columns. (Sorted by date, the UI would nest the children under a collapsed
    parent, and a shared view cannot say which runs to expand: MLflow 3.17 drops ``runsExpanded`` from it.)
    The full-precision metrics stay out of view (the Columns menu adds them, numerically sortable): the UI prints
    them unrounded, orders their columns by name and cuts their headers alike."""
    figures = [f"tags.`{tag_key(name)}`" for name in FIGURE_TAGS]
    columns = [*figures, "attributes.`Dataset`"]
    widths = {column: HEADER_PX + CHAR_PX * max(len(tag_key(name)), VALUE_CHARS)
              for column, name in zip(figures, FIGURE_TAGS)}
    return json.dumps({"selectedColumns": columns, "columnOrder": columns, "columnWidths": widths,
                       "orderByKey": RUN_NAME_KEY, "orderByAsc": True})


def _scale_note() -> str:
    return "any scale: append `scale=tiny|cpu|quickstart|paper` (the runs carry `tags.scale`)"


def experiment_description(name: str, cfg: DictConfig | None = None) -> str:
    """What a SPADE experiment holds, which paper table it reproduces and the commands that regenerate it."""
    columns = ", ".join(f"`{m.mlflow_key}`" for m in METRICS.values())
    table = next((t for t in TABLES.values() if t.experiment == name), None)
    if table is not None:
        return (
            f"Reproduces **{table.title}** of the SPADE paper (AAMAS 2026). One run per row, named after the "
            f"row: {', '.join(table.rows)}. Every row logs {columns}, so the runs table with those columns is "
            f"the paper's table.\n\n"
            f"Regenerate: `python -m spade.train +experiment={table.composition}` ({_scale_note()}); one row: "
            f"`python -m spade.train +experiment=ROW`. Print the table in the paper's layout: "
            f"`python -m spade.report table={table.key}`."
        )
    if name == "quickstart":
        return (
            "The README's first command (`make quickstart`, i.e. `python -m spade.train +experiment=quickstart`): "
            "a small Cond-DBC student trained on L-shape demonstrations with a tiny conditional expert's guidance, "
            "tested next to the same student untrained and the classical baselines. Not a paper table; it shows "
            "the whole pipeline on a CPU (each run's description gives its measured wall time). Regenerate: "
            "`make quickstart`."
        )
    if name == "smoke":
        return (
            "Pipeline check (`python -m spade.train +experiment=smoke`, seconds at `scale=tiny`): data "
            "generation, a tiny conditional expert (registered) and a few steps of a Cond-DBC student. Its "
            "figures mean nothing; it reproduces no paper table. Regenerate: `python -m spade.train +experiment=smoke`."
        )
    if name == "evaluation":
        return (
            "Checkpoints tested on a data config's test set by `python -m spade.evaluate ckpt_path=PATH "
            "[data=lshape|ushape|transfer] [scale=...]`; one run per evaluation. Reproduces no table by itself: "
            f"it re-tests students and experts of the tables' rows. Columns: {columns}."
        )
    if name.startswith("sweep_"):
        search = name[len("sweep_"):]
        return (
            f"Optuna search `{search}` (sweeps/search/{search}.yaml): each trial is one run, its lambda in "
            f"`tags.lambda`. Supports Table 1's Cond-DBC rows (the guidance weight); it is not a paper table. "
            f"Regenerate: `python -m spade.train --config-dir sweeps +search={search}` ({_scale_note()})."
        )
    return (
        f"Runs of `python -m spade.train` with `tags.table={name}`; not one of the paper's tables. Each run's "
        f"description gives the command that regenerates it, and its composed config is the artifact "
        f"`config/train.yaml`."
    )


def _set_tag(client: Any, experiment_id: str, key: str, value: str, *, keep_existing: bool = False) -> None:
    """Set one experiment tag, safely when a parallel job sets the same tag at the same moment.

    MLflow's SQL store writes an experiment tag as look-up-then-insert: two jobs of a sweep that start together
    both find the tag absent and the second insert fails on the table's unique key (``IntegrityError``, a
    ``RestException`` through ``mlflow server``). The tag is then set (by the other job): read it back, and set it
    again only when it still differs (``keep_existing``: any value the other job wrote is kept).
    """
    from mlflow.exceptions import MlflowException

    try:
        client.set_experiment_tag(experiment_id, key, value)
    except MlflowException:
        current = (client.get_experiment(experiment_id).tags or {}).get(key)
        if current is None:
            raise
        if current != value and not keep_existing:
            client.set_experiment_tag(experiment_id, key, value)  # the row exists now: this write is an update


def ensure_experiment_tags(client: Any, experiment: Any, cfg: DictConfig | None = None) -> None:
    """Tag ``experiment`` as model training, store SPADE's runs view (:func:`runs_view_state`) and add the
    description where there is none (a description a person wrote in the UI is kept)."""
    tags = dict(experiment.tags or {})
    eid = experiment.experiment_id
    if tags.get(KIND_TAG) != KIND_TRAINING:
        _set_tag(client, eid, KIND_TAG, KIND_TRAINING)
    if not tags.get(NOTE_TAG):
        _set_tag(client, eid, NOTE_TAG, experiment_description(experiment.name, cfg), keep_existing=True)
    view = runs_view_state()
    if tags.get(VIEW_TAG) != view:
        _set_tag(client, eid, VIEW_TAG, view)
