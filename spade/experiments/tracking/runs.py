"""An MLflow run from start to end: opened, its config and process recorded, described when it finishes, its status.

* :func:`bind_experiment` opens the logger's run (a new one, or the resumed ``run_id``) safely under parallel jobs
  and tags its experiment (:mod:`~spade.experiments.tracking.experiment_tags`).
* :func:`start_run_logging` records the parameters that describe the method
  (:mod:`~spade.experiments.tracking.params`), the whole config as ``config/train.yaml`` and the FID extractor's
  identity; :func:`record_process` tags the run with its host, process id and process start time while it runs
  (a resumed run is RUNNING again).
* :func:`finish_run` logs the best and last checkpoints, a student's best one as the run's MLflow Model ``model``
  (:mod:`~spade.experiments.tracking.logged_model`), the training-progress picture
  (:mod:`spade.training.progress_picture`), the datasets as inputs
  (:mod:`~spade.experiments.tracking.dataset_inputs`) and the description
  (:mod:`~spade.experiments.tracking.descriptions`), the classical baselines and the untrained model as child runs
  (:mod:`~spade.experiments.tracking.predictors`) and the run's report (:mod:`~spade.experiments.tracking.run_report`),
  drops the process tags of a run that ended, and registers the model when the row asks;
  :func:`finish_evaluation` does the same for ``spade.evaluate``'s run. :func:`last_run` is where the run lives.
* A run that does not finish is closed honestly: :func:`mark_run_ended` marks it KILLED (a signal, Ctrl+C:
  :func:`spade.experiments.lifecycle.install_signal_handlers`) or FAILED (any other exception), and
  :func:`mark_stale_runs` (run by the next ``spade.train`` of the same row) marks RUNNING runs whose process is
  gone (a ``kill -9``, a power cut) KILLED, with a message. The process tags stay on a KILLED or FAILED run.

Only Lightning's public ``MLFlowLogger`` API is used (``experiment``: its ``MlflowClient``; ``run_id``;
``experiment_id``) and MLflow's own client.
"""

from __future__ import annotations

import contextlib
import datetime
import fcntl
import logging
import os
import signal
import socket
import time
import weakref
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import lightning as L
from lightning.pytorch.loggers import Logger, MLFlowLogger
from lightning.pytorch.utilities import rank_zero_only
from omegaconf import DictConfig, OmegaConf

from spade.experiments.lifecycle import signal_received
from spade.experiments.tracking.dataset_inputs import DatasetUse, dataset_uses, log_dataset_inputs
from spade.experiments.tracking.descriptions import (
    model_description,
    prerequisite_uses,
    run_description,
    version_description,
)
from spade.experiments.tracking.experiment_tags import NOTE_TAG, ensure_experiment_tags
from spade.experiments.tracking.logged_model import (
    LoggedStudent,
    describe_logged_model,
    model_note,
    try_log_student_model,
)
from spade.experiments.tracking.logger import held_metrics
from spade.experiments.tracking.params import run_params
from spade.experiments.tracking.predictors import is_predictor_run
from spade.utils.processes import pid_alive, process_start

log = logging.getLogger(__name__)


def mlflow_logger(loggers: list[Logger]) -> MLFlowLogger | None:
    """The run's MLflow logger among ``loggers`` (the first one); None when the run does not log to MLflow."""
    return next((lg for lg in loggers if isinstance(lg, MLFlowLogger)), None)


# -- opening the run --------------------------------------------------------------------------------------------
_bound: weakref.WeakSet[MLFlowLogger] = weakref.WeakSet()  # loggers whose run bind_experiment opened or resumed


def bind_experiment(ml: MLFlowLogger, cfg: DictConfig | None = None) -> None:
    """Open the logger's MLflow run (a new one in its experiment, or the resumed ``run_id``), safely under parallel
    jobs, and tag its experiment.

    Lightning's ``MLFlowLogger`` looks its experiment up and creates it when absent: two jobs of a sweep that
    start together into an empty store both find it absent and the second ``create_experiment`` fails. That
    failure leaves the logger unbound, so a second ``ml.experiment`` looks the experiment up again and finds the
    one the parallel job created. The experiment gets
    :func:`~spade.experiments.tracking.experiment_tags.ensure_experiment_tags` (also one created before SPADE
    tagged experiments); a resumed run's experiment is tagged the same way. A deleted experiment of that name
    raises Lightning's error, as before.
    """
    from mlflow.exceptions import MlflowException

    try:
        client = ml.experiment
    except MlflowException:
        client = ml.experiment  # created meanwhile by a parallel job: this lookup finds it
    _bound.add(ml)  # the run is open: from here on mark_run_ended closes it when the run fails
    ensure_experiment_tags(client, client.get_experiment(ml.experiment_id), cfg)


def bound_run_id(ml: MLFlowLogger) -> str | None:
    """The logger's MLflow run id, without opening a run: on rank zero the run :func:`bind_experiment` opened or
    resumed (None before it did, or when it failed); on other ranks, whose logger holds no client, the ``run_id``
    it was made with (a resumed run; None for a new one)."""
    if rank_zero_only.rank == 0 and ml not in _bound:
        return None
    return ml.run_id


@rank_zero_only  # under DDP, other ranks' MLflow loggers hold no run (their experiment is a no-op)
def start_run_logging(cfg: DictConfig, model: L.LightningModule, loggers: list[Logger]) -> None:
    """Log the parameters that describe the method (:func:`~spade.experiments.tracking.params.run_params`: no
    bookkeeping, no copies), the whole composed config as ``config/train.yaml`` and the FID extractor's identity
    (tag ``fid_extractor``)."""
    ml = mlflow_logger(loggers)
    if ml is None:
        return
    bind_experiment(ml, cfg)
    params = run_params(OmegaConf.to_container(cfg, resolve=True))
    fid = getattr(getattr(model, "test_metrics", None), "fid_identity", None)
    # A resumed run continues an MLflow run whose params are immutable: log only what it lacks (ckpt_path and
    # anything else set differently for the resume is recorded as a tag instead).
    existing = ml.experiment.get_run(ml.run_id).data.params
    if existing:
        changed = {k: v for k, v in params.items() if k in existing and existing[k] != str(v)}
        for key, value in changed.items():
            ml.experiment.set_tag(ml.run_id, f"resumed/{key}", str(value))
        params = {k: v for k, v in params.items() if k not in existing}
    if params:
        ml.log_hyperparams(params)
    ml.experiment.log_text(ml.run_id, OmegaConf.to_yaml(cfg, resolve=True), "config/train.yaml")
    if fid:
        ml.experiment.set_tag(ml.run_id, "fid_extractor", fid)


# -- the store ------------------------------------------------------------------------------------------------------
@contextlib.contextmanager
def store_lock(tracking_uri: str | None) -> Iterator[None]:
    """An exclusive ``fcntl`` lock on ``<store>.lock`` beside a local SQLite store (nothing for a server or a file
    store): the processes of SPADE that open one store take turns while MLflow creates its tables."""
    from spade.experiments.checks.store import _store_path

    uri = str(tracking_uri or "")
    path = _store_path(uri) if uri.startswith("sqlite:") else None
    if path is None:
        yield
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path.with_name(path.name + ".lock"), "a") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


def ensure_store(tracking_uri: str | None) -> None:
    """Open the store at ``tracking_uri`` once, creating a fresh SQLite store's tables under :func:`store_lock`.

    MLflow creates a new SQLite store's schema (its Alembic migrations) the first time a client opens it, and two
    processes doing so at once collide (``duplicate column name``): two ``spade.train`` started together on a fresh
    store crashed one of them. Under the lock the first creates the tables and the second finds them. A store that
    cannot be opened is left to the run's own logger to report."""
    if not tracking_uri or not str(tracking_uri).startswith("sqlite:"):
        return
    from mlflow import MlflowClient

    with store_lock(tracking_uri):
        MlflowClient(tracking_uri=str(tracking_uri)).search_experiments(max_results=1)


def ensure_logger_store(cfg: DictConfig) -> None:
    """:func:`ensure_store` for the store of ``cfg``'s MLflow logger (nothing without one)."""
    logger_cfg = (cfg.get("logger") or {}).get("mlflow")
    if not logger_cfg or "MLFlowLogger" not in str(logger_cfg.get("_target_", "")):
        return
    ensure_store(OmegaConf.select(cfg, "logger.mlflow.tracking_uri"))


# -- the run's process and status -------------------------------------------------------------------------------
PROCESS_TAGS = ("spade.host", "spade.pid", "spade.proc_start")  # a RUNNING run's process (mark_stale_runs)


def process_tags() -> dict[str, str]:
    """This process as :data:`PROCESS_TAGS`: host name, process id and the process's start time (so that a
    recycled pid is not taken for it). Set while a run is RUNNING; removed when it finishes
    (:func:`drop_process_tags`)."""
    tags = {"spade.host": socket.gethostname(), "spade.pid": str(os.getpid())}
    start = process_start(os.getpid())
    if start is not None:
        tags["spade.proc_start"] = start
    return tags


def record_process(loggers: list[Logger], resumed: bool) -> None:
    """Tag the MLflow run with this process (for :func:`mark_stale_runs`); a resumed run is RUNNING again."""
    ml = mlflow_logger(loggers)
    run_id = bound_run_id(ml) if ml is not None else None
    if run_id is None:
        return
    client = ml.experiment
    for key, value in process_tags().items():
        client.set_tag(run_id, key, value)
    if resumed and client.get_run(run_id).info.status != "RUNNING":
        client.update_run(run_id, status="RUNNING")
        client.set_tag(run_id, "spade.end_reason", "")


def mark_run_ended(loggers: list[Logger], exc: BaseException) -> None:
    """Close this process's MLflow run after ``exc``: KILLED for a signal or Ctrl+C, FAILED otherwise."""
    ml = mlflow_logger(loggers)
    run_id = bound_run_id(ml) if ml is not None else None
    if run_id is None:
        return  # no run was opened (or the one to resume could not be): nothing to close
    sig = signal_received()
    killed = sig is not None or isinstance(exc, KeyboardInterrupt)
    status = "KILLED" if killed else "FAILED"
    reason = f"signal {signal.Signals(sig).name}" if sig is not None else f"{type(exc).__name__}: {exc}"
    try:
        ml.experiment.set_tag(run_id, "spade.end_reason", reason[:4000])
        ml.experiment.set_terminated(run_id, status)
        log.info("MLflow run %s marked %s (%s)", run_id, status, reason[:200])
    except Exception as err:  # never hide the original error
        log.warning("could not mark MLflow run %s %s: %s", run_id, status, err)


def mark_evaluation_ended(loggers: list[Logger], exc: BaseException) -> None:
    """:func:`mark_run_ended` for ``spade.evaluate``'s run, which Lightning opened during the test (SPADE binds it
    only when the evaluation finishes): Lightning's teardown marks an interrupted test FAILED; a signal or Ctrl+C
    is KILLED."""
    ml = mlflow_logger(loggers)
    if ml is None:
        return
    if ml not in _bound:
        try:
            ml.run_id  # the run Lightning opened (MLFlowLogger's public property)
        except Exception as err:  # noqa: BLE001 - never hide the original error
            log.warning("could not find the evaluation's MLflow run: %s", err)
            return
        _bound.add(ml)
    mark_run_ended(loggers, exc)


def mark_stale_runs(cfg: DictConfig) -> list[str]:
    """Mark KILLED the RUNNING runs of this row (same MLflow experiment and run name) whose process is gone.

    A run's process is known by its ``spade.host`` / ``spade.pid`` / ``spade.proc_start`` tags; runs started on
    another host are left alone (their process cannot be checked from here) and named in the log. Returns one
    message per run marked.
    """
    logger_cfg = (cfg.get("logger") or {}).get("mlflow")
    if not logger_cfg or "MLFlowLogger" not in str(logger_cfg.get("_target_", "")):
        return []
    from mlflow import MlflowClient

    resolved = OmegaConf.to_container(logger_cfg, resolve=True)
    ensure_store(resolved.get("tracking_uri"))  # a fresh store's tables, created by one process at a time
    client = MlflowClient(tracking_uri=resolved.get("tracking_uri"))
    experiment = client.get_experiment_by_name(str(resolved.get("experiment_name")))
    if experiment is None:
        return []
    run_name = str(resolved.get("run_name"))
    host = socket.gethostname()
    messages = []
    for run in client.search_runs([experiment.experiment_id], filter_string="attributes.status = 'RUNNING'",
                                  max_results=1000):
        if run.info.run_name != run_name or is_predictor_run(run):
            continue  # another row's run, or a row's baseline / untrained model (a child run: no process of its own)
        tags = run.data.tags
        pid = tags.get("spade.pid")
        if pid is None:
            continue  # not started by this version of spade.train: its process cannot be identified
        if tags.get("spade.host") != host:
            log.warning("MLflow run %s (%s) is RUNNING on host %s: left as it is", run.info.run_id, run_name,
                        tags.get("spade.host"))
            continue
        if pid_alive(int(pid), tags.get("spade.proc_start")):
            continue
        started = datetime.datetime.fromtimestamp(run.info.start_time / 1000).isoformat(timespec="seconds")
        message = (f"MLflow run {run.info.run_id} ({experiment.name}/{run_name}, started {started}) was still "
                   f"RUNNING although its process {pid} on {host} is gone: marked KILLED")
        client.set_tag(run.info.run_id, "spade.end_reason",
                       f"process {pid} on {host} ended without closing the run; marked KILLED by a later spade.train")
        client.set_terminated(run.info.run_id, "KILLED")
        log.warning(message)
        messages.append(message)
    return messages


# -- finishing the run ------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class RunRef:
    """Where a finished run lives, for the closing lines of ``spade.train``."""

    tracking_uri: str
    experiment_id: str
    run_id: str
    run_name: str
    model_uri: str | None = None  # the student's MLflow Model logged on the run (runs:/RUN_ID/model), if any


_last_run: RunRef | None = None


def last_run() -> RunRef | None:
    """The run most recently finished by :func:`finish_run` in this process (a row after its prerequisites)."""
    return _last_run


def _picture_paths(client: Any, run_id: str) -> list[str]:
    """The run's pictures: the training-progress picture, then the prediction pictures."""
    try:
        root = sorted(a.path for a in client.list_artifacts(run_id) if a.path.endswith(".png"))
        return root + sorted(a.path for a in client.list_artifacts(run_id, "predictions") if a.path.endswith(".png"))
    except Exception:  # noqa: BLE001 - listing artifacts is a nicety of the description
        return []


def _references_note(metrics: dict[str, float], run: tuple[str, str]) -> str:
    """Where the run's references and report are (a run with test figures: :func:`_predictors_and_report`)."""
    from spade.experiments.tracking.links import artifact_url
    from spade.experiments.tracking.predictors import predictors
    from spade.experiments.tracking.run_report import CSV, MARKDOWN, REPORT_DIR

    if not any(k.startswith("test/") for k in metrics):
        return ""
    found = predictors(metrics)
    text = ""
    if found:
        names = ", ".join(f"`{p.name}`" for p in found)
        text += (f"\n\nThe references are child runs of this run ({names}), with this run's metric names: "
                 "in the runs table (SPADE's view, sorted by name) they follow it, one line each.")
    links = ", ".join(f"[{REPORT_DIR}/{f}]({artifact_url('', *run, f'{REPORT_DIR}/{f}')})" for f in (MARKDOWN, CSV))
    return text + f"\n\nReport: {links}."


def describe_run(cfg: DictConfig, ml: MLFlowLogger, datamodule: Any, contexts: tuple[str, ...] | None = None,
                 logged_model: LoggedStudent | None = None) -> tuple[list[DatasetUse], dict[str, float], str]:
    """Log the run's dataset inputs and set its description (with the MLflow Model logged on the run, when one
    was); returns (dataset uses, the run's metrics, the description)."""
    client, run_id = ml.experiment, ml.run_id
    uses = dataset_uses(datamodule) if datamodule is not None else []
    if contexts is not None:
        uses = [u for u in uses if u.context in contexts]
    try:
        log_dataset_inputs(client, run_id, uses)
    except (OSError, ValueError) as exc:  # an unreadable manifest: the run itself is fine, say so
        log.warning("datasets not logged as MLflow inputs: %s", exc)
    run = client.get_run(run_id)
    metrics = {**dict(run.data.metrics), **held_metrics(ml)}  # the references' figures: held back by the logger
    history = margin_history(client, run_id) if "margin/active" in metrics else None
    end = run.info.end_time or int(time.time() * 1000)
    seconds = (end - run.info.start_time) / 1000.0 if run.info.start_time else None
    description = run_description(cfg, metrics, uses, prerequisite_uses(cfg, client), _picture_paths(client, run_id),
                                  (str(run.info.experiment_id), run_id), history, seconds)
    description += _references_note(metrics, (str(run.info.experiment_id), run_id)) + model_note(logged_model)
    client.set_tag(run_id, NOTE_TAG, description)
    if logged_model is not None:
        _nicety("the logged model's description", describe_logged_model, client, logged_model, cfg, metrics,
                (str(run.info.experiment_id), run_id, str(run.info.run_name)))
    global _last_run
    _last_run = RunRef(str(client.tracking_uri), str(run.info.experiment_id), run_id, str(run.info.run_name),
                       logged_model.run_uri if logged_model is not None else None)
    return uses, metrics, description


def margin_history(client: Any, run_id: str) -> list[tuple[int, float, float]]:
    """A guided student's margin activity per epoch, ``[(epoch, active, value)]``, from the run's ``margin/*``
    (logged at the global step of each epoch's validation, tag ``spade.margin_step=global``; older runs: step =
    epoch)."""
    from spade.training.progress_picture import epoch_series

    series = epoch_series(client, run_id)
    values = dict(series.get("margin/value", []))
    return [(epoch, active, values.get(epoch, float("nan"))) for epoch, active in series.get("margin/active", [])]


def _nicety(what: str, step: Any, *args: Any) -> Any:
    """Run one of the deliverables a finished run adds to its record; a failure is a warning, never the run's."""
    try:
        return step(*args)
    except Exception as exc:  # noqa: BLE001 - the run itself finished: its record must not fail it
        log.warning("%s not logged: %s", what, exc)
        return None


def _predictors_and_report(cfg: DictConfig, client: Any, run_id: str, uses: list[DatasetUse],
                           metrics: dict[str, float], description: str) -> None:
    """The run's references as child runs (:mod:`~spade.experiments.tracking.predictors`) and its report
    (:mod:`~spade.experiments.tracking.run_report`)."""
    from spade.experiments.tracking.descriptions import what_it_is
    from spade.experiments.tracking.predictors import log_predictor_runs
    from spade.experiments.tracking.run_report import log_run_report

    tags = dict(cfg.get("tags") or {})
    role = str(tags.get("role") or "model")
    test_uses = [u for u in uses if u.context == "test"]
    _nicety("predictor runs", log_predictor_runs, client, run_id, role, what_it_is(tags), test_uses, metrics)
    _nicety("run report", log_run_report, client, run_id, str(cfg.get("run_name") or "run"), description, metrics,
            role)


def drop_process_tags(client: Any, run_id: str) -> None:
    """Remove the process tags (:func:`process_tags`) and an empty ``spade.end_reason`` from a FINISHED run: they
    identify a running run's process for :func:`mark_stale_runs` and mean nothing once it finished. A RUNNING run
    keeps them (Lightning closes the run when testing ends; with neither fit nor test it is still open), and so
    does a KILLED or FAILED one (which process it was is part of what went wrong)."""
    run = client.get_run(run_id)
    if run.info.status != "FINISHED":
        return
    tags = run.data.tags
    for key in (*PROCESS_TAGS, "spade.end_reason"):
        if key in tags and (key != "spade.end_reason" or not tags[key]):
            client.delete_tag(run_id, key)


@rank_zero_only
def finish_run(cfg: DictConfig, trainer: L.Trainer, model: L.LightningModule, loggers: list[Logger]) -> None:
    """Log the checkpoints, a student's best one as the run's MLflow Model ``model``
    (:mod:`~spade.experiments.tracking.logged_model`), the datasets as inputs and the run's description; the
    baselines and the untrained model as child runs, the report (``report/``) and the training-progress picture;
    register the checkpoint when asked."""
    ml = mlflow_logger(loggers)
    if ml is None:
        return
    from spade.experiments.lifecycle import best_checkpoint_path, last_checkpoint_path

    paths = {kind: path for kind, path in (("best", best_checkpoint_path(trainer)),
                                           ("last", last_checkpoint_path(trainer))) if path}
    for kind, path in paths.items():
        ml.experiment.log_artifact(ml.run_id, path, artifact_path=f"checkpoints/{kind}")
    client, run_id = ml.experiment, ml.run_id
    if cfg.get("train", True):
        from spade.training.progress_picture import log_progress_picture

        _nicety("training-progress picture", log_progress_picture, client, run_id, f"{cfg.get('run_name')}: "
                "training by epoch")
    logged = try_log_student_model(cfg, str(client.tracking_uri), run_id, paths.get("best") or paths.get("last"))
    uses, metrics, description = describe_run(cfg, ml, getattr(trainer, "datamodule", None), logged_model=logged)
    _predictors_and_report(cfg, client, run_id, uses, metrics, description)
    _nicety("process tags' removal", drop_process_tags, client, run_id)
    from spade.experiments.registry import data_fingerprint, register_checkpoint, registry_name

    name = registry_name(cfg)
    if name and paths:
        tags = {**dict(cfg.get("tags") or {}), **dict((cfg.get("registry") or {}).get("tags") or {})}
        register_checkpoint(ml, name, f"checkpoints/{'best' if 'best' in paths else 'last'}", tags=tags,
                            data_fingerprint=data_fingerprint(cfg), description=model_description(cfg, uses),
                            version_description=version_description(cfg, ml, metrics),
                            promote=bool((cfg.get("registry") or {}).get("promote", False)))


@rank_zero_only
def finish_evaluation(cfg: DictConfig, trainer: L.Trainer, loggers: list[Logger]) -> None:
    """``spade.evaluate``'s run: the test dataset as input and a description with the figures and baselines, the
    baselines as child runs and the report (``report/``)."""
    ml = mlflow_logger(loggers)
    if ml is None:
        return
    bind_experiment(ml, cfg)
    if cfg.get("source_seed") is not None:  # a training run's checkpoint tested elsewhere: counted under its seed
        ml.experiment.log_param(ml.run_id, "cfg/seed", int(cfg.source_seed))
    uses, metrics, description = describe_run(cfg, ml, getattr(trainer, "datamodule", None), contexts=("test",))
    _predictors_and_report(cfg, ml.experiment, ml.run_id, uses, metrics, description)
