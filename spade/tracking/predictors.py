"""The predictors a run is compared with, side by side in the MLflow runs table: child runs of the model's run.

A tested run's classical baselines (``test/baseline/<name>/...``) and, with ``test_untrained=true``, the same model
before training (``untrained/...``) are **only** child runs of the model's run: SPADE's MLflow logger
(:mod:`~spade.tracking.logger`) holds their figures back from the run itself and
:func:`log_predictor_runs` logs each of them as a child run (tag ``mlflow.parentRunId``), named
``<run name>/baseline-<name>`` and ``<run name>/untrained``, with the model's own metric names (``test/ape_cm``,
``test/planner/ape_cm``, ...) at the model's test step (:data:`TEST_STEP`): the runs table shows the model and its
references as rows under one another, the same column holding the same figure, and a chart of ``test/ape_cm``
shows one bar or dot per predictor at one x. A run driven in closed loop (``closed_loop=true``) also gives each
baseline's child run its closed-loop figures (``closed_loop/baseline/<name>/<key>`` as ``closed_loop/<key>``, the
student's names, at the same step; the run itself keeps them too, for the closed-loop page), so that a chart of
``closed_loop/ape_cm`` compares the student with the planners it was driven against. Each child run carries
``spade.predictor=<name>`` (the model's run carries its role: ``student``, ``expert``), its colour in the UI's charts
(``mlflow.runColor``: one per predictor kind, :func:`spade.utils.palette.predictor_colour`), the row's ``table``,
``row``, ``scale`` and ``shape`` tags, the test dataset as its input and a one-line description. SPADE's runs view
sorts by run name, so that each run is followed by its children, one line each
(:func:`~spade.tracking.experiment_tags.runs_view_state`).

Readers that want a run's figures with its references' under the old names (``spade.report``'s tables, the
teacher page: ``test/baseline/<name>/...``, ``untrained/...``) fold the children back in with
:func:`with_predictor_figures`; runs logged before the children existed keep those names on the run itself, and
both read alike. Queries that count a row's runs match runs by their run name, which a child run never shares with
its parent; :func:`is_predictor_run` and :data:`TOP_LEVEL_FILTER` tell them apart explicitly
(``search_runs(..., filter_string=TOP_LEVEL_FILTER)``).

This module imports neither torch nor Lightning (``spade.report`` reads through it).
"""

from __future__ import annotations

import logging
import re
import time
from dataclasses import dataclass
from typing import Any
from spade.metrics.catalog import BASELINE_ROW_LABELS as BASELINE_LABELS
from spade.tracking.dataset_inputs import log_dataset_inputs
from spade.tracking.experiment_tags import NOTE_TAG
from spade.tracking.figure_tags import figure_tags
from spade.utils.palette import predictor_colour

log = logging.getLogger(__name__)

PREDICTOR_TAG = "spade.predictor"  # what predicted a run's figures: the model's role, untrained, baseline-<name>
PARENT_TAG = "mlflow.parentRunId"  # MLflow's nesting of runs (the runs table shows children under their parent)
TOP_LEVEL_FILTER = f"tags.`{PARENT_TAG}` IS NULL"  # search_runs filter: the rows' own runs, not their predictors
ROW_TAGS = ("table", "row", "scale", "shape")  # copied from the model's run onto each predictor's run
MODEL_TAGS = ("approach", "size", "recipe")  # also onto the untrained model's run (the same architecture)
COLOUR_TAG = "mlflow.runColor"  # the run's colour in the MLflow UI's charts and runs table
TEST_STEP = 0  # the step of every test figure: the model's (spade.tracking.logger) and its references'
REFERENCE_PREFIXES = ("test/baseline/", "untrained/")  # the references' figures as the test step names them


def is_reference_metric(key: str) -> bool:
    """Whether ``key`` is a reference's figure (a baseline's, the untrained model's) rather than the model's."""
    return key.startswith(REFERENCE_PREFIXES)


@dataclass(frozen=True)
class Predictor:
    """One reference predictor of a run: its name (``untrained``, ``baseline-straight``), a label for people and
    its figures under the model's metric names (``test/ape_cm``, ...)."""

    name: str
    label: str
    metrics: dict[str, float]


def predictors(metrics: dict[str, float]) -> list[Predictor]:
    """The baselines (``test/baseline/<name>/<key>``, and driven in closed loop ``closed_loop/baseline/<name>/<key>``)
    and the untrained model (``untrained/<key>``; the baselines it was tested next to, ``untrained/baseline/...``, are
    the same figures again and left out) of a run's metrics, as :class:`Predictor` s with the model's names
    (``test/<key>``, ``closed_loop/<key>``). The untrained model also carries the model's ``model/params`` (the same
    network)."""
    baselines: dict[str, dict[str, float]] = {}
    untrained: dict[str, float] = {}
    for key, value in metrics.items():
        if match := re.fullmatch(r"(test|closed_loop)/baseline/([^/]+)/(.+)", key):
            baselines.setdefault(match.group(2), {})[f"{match.group(1)}/{match.group(3)}"] = float(value)
        elif key.startswith("untrained/") and not key.startswith("untrained/baseline/"):
            untrained[f"test/{key[len('untrained/'):]}"] = float(value)
    out = [Predictor(f"baseline-{name}", f"baseline: {BASELINE_LABELS.get(name, name)}", figures)
           for name, figures in sorted(baselines.items())]
    if untrained:
        if "model/params" in metrics:
            untrained["model/params"] = float(metrics["model/params"])
        out.append(Predictor("untrained", "untrained", untrained))
    return out


def is_predictor_run(run: Any) -> bool:
    """Whether ``run`` (an MLflow ``Run``) is a predictor's child run rather than a row's own run."""
    tags = run.data.tags
    return bool(tags.get(PARENT_TAG)) or tags.get(PREDICTOR_TAG, "").startswith(("baseline-", "untrained"))


def _note(predictor: Predictor, row: str, what: str) -> str:
    if predictor.name == "untrained":
        return (f"The {what} of row **{row}** before any training, tested on the same test set (its parent run): "
                "what training has to improve on.")
    driven = any(k.startswith("closed_loop/") for k in predictor.metrics)
    return (f"Classical predictor ({predictor.label[len('baseline: '):]}) on the test set of row **{row}** (its "
            "parent run): no learning, the same instances; a learned model that does not beat it has learned "
            "nothing worth deploying." + (" Its closed_loop/* figures: the same planner driven through the parent's "
                                          "closed-loop scenarios." if driven else ""))


def log_predictor_runs(client: Any, run_id: str, role: str | None = None, what: str = "model",
                       test_uses: list[Any] | None = None, metrics: dict[str, float] | None = None) -> dict[str, str]:
    """Log the predictors of run ``run_id`` (:func:`predictors` of ``metrics``, by default the run's own: those
    of a run whose logger held its references back are the run's and the held ones together) as its child runs;
    returns ``{predictor name: child run id}``. The run itself is tagged ``spade.predictor=<role>``; each run gets
    its predictor kind's colour.

    Idempotent: a child run that exists (a run tested again) is updated, not doubled. ``test_uses``: the test
    dataset(s) (:class:`~spade.tracking.dataset_inputs.DatasetUse`), logged as each child's input.
    """
    from mlflow.entities import Metric, RunTag

    run = client.get_run(run_id)
    found = predictors(dict(metrics) if metrics is not None else dict(run.data.metrics))
    if role:
        client.set_tag(run_id, PREDICTOR_TAG, role)
        client.set_tag(run_id, COLOUR_TAG, predictor_colour(role))
    if not found:
        return {}
    experiment_id, name, tags = run.info.experiment_id, run.info.run_name, run.data.tags
    existing = {r.data.tags.get(PREDICTOR_TAG): r.info.run_id
                for r in client.search_runs([experiment_id], filter_string=f"tags.`{PARENT_TAG}` = '{run_id}'",
                                            max_results=1000)}
    row = tags.get("row") or name
    out: dict[str, str] = {}
    for predictor in found:
        child_tags = {PARENT_TAG: run_id, PREDICTOR_TAG: predictor.name, NOTE_TAG: _note(predictor, row, what),
                      COLOUR_TAG: predictor_colour(predictor.name),
                      **{k: tags[k] for k in ROW_TAGS if tags.get(k)}, **figure_tags(predictor.metrics)}
        if predictor.name == "untrained":
            child_tags.update({k: tags[k] for k in (*MODEL_TAGS, "role") if tags.get(k)})
        child = existing.get(predictor.name)
        if child is None:
            child = client.create_run(experiment_id, run_name=f"{name}/{predictor.name}").info.run_id
        now = int(time.time() * 1000)
        client.log_batch(child, metrics=[Metric(k, v, now, TEST_STEP) for k, v in sorted(predictor.metrics.items())],
                         tags=[RunTag(k, str(v)) for k, v in child_tags.items()])
        if test_uses:
            try:
                log_dataset_inputs(client, child, list(test_uses))
            except (OSError, ValueError) as exc:  # an unreadable manifest: the figures are logged, say so
                log.warning("test dataset not logged as the input of %s: %s", predictor.name, exc)
        client.set_terminated(child, "FINISHED")
        out[predictor.name] = child
    return out


def predictor_figures(metrics: dict[str, float]) -> dict[str, list[str]]:
    """Which figures each predictor's child run gets from ``metrics`` (:func:`predictors`): ``{name: sorted keys}``,
    to tell whether figures logged after the child runs (a closed loop driven after the test) call for them again."""
    return {p.name: sorted(p.metrics) for p in predictors(metrics)}


def reference_key(predictor: str, key: str) -> str | None:
    """A child run's metric ``key`` (``test/ape_cm``) under its parent's name for it (``test/baseline/straight/ape_cm``,
    ``untrained/ape_cm``, ``closed_loop/baseline/shortest/ape_cm``); None for a key the parent never carried for that
    predictor."""
    if key.startswith("closed_loop/") and predictor.startswith("baseline-"):
        return f"closed_loop/baseline/{predictor[len('baseline-'):]}/{key[len('closed_loop/'):]}"
    if not key.startswith("test/"):
        return None
    if predictor == "untrained":
        return "untrained/" + key[len("test/"):]
    if predictor.startswith("baseline-"):
        return f"test/baseline/{predictor[len('baseline-'):]}/{key[len('test/'):]}"
    return None


def with_predictor_figures(client: Any, runs: list[Any]) -> list[Any]:
    """``runs`` (MLflow ``Run`` s) with their predictors' child runs folded back in: each run's metrics gain its
    children's figures under the names the run itself would have carried (:func:`reference_key`), where the run
    does not carry them already (a run logged before its references became child runs only). Child runs among
    ``runs`` are returned as they are. One search per experiment."""
    from mlflow.entities import Metric, Run, RunData

    parents = {r.info.run_id: r for r in runs if not is_predictor_run(r)}
    if not parents:
        return list(runs)
    experiments = sorted({str(r.info.experiment_id) for r in parents.values()})
    extra: dict[str, dict[str, float]] = {}
    token = None
    while True:
        page = client.search_runs(experiments, filter_string=f"tags.`{PARENT_TAG}` IS NOT NULL", max_results=1000,
                                  page_token=token)
        for child in page:
            parent = child.data.tags.get(PARENT_TAG)
            predictor = child.data.tags.get(PREDICTOR_TAG, "")
            if parent not in parents:
                continue
            for key, value in child.data.metrics.items():
                name = reference_key(predictor, key)
                if name is not None:
                    extra.setdefault(parent, {})[name] = float(value)
        token = page.token
        if not token:
            break
    out = []
    for run in runs:
        figures = {k: v for k, v in extra.get(run.info.run_id, {}).items() if k not in run.data.metrics}
        if not figures:
            out.append(run)
            continue
        metrics = [Metric(k, float(v), 0, TEST_STEP) for k, v in {**run.data.metrics, **figures}.items()]
        data = RunData(metrics=metrics, params=list(_params(run)), tags=list(_tags(run)))
        out.append(Run(run.info, data, getattr(run, "inputs", None), getattr(run, "outputs", None)))
    return out


def _params(run: Any) -> Any:
    from mlflow.entities import Param

    return (Param(k, v) for k, v in run.data.params.items())


def _tags(run: Any) -> Any:
    from mlflow.entities import RunTag

    return (RunTag(k, v) for k, v in run.data.tags.items())
