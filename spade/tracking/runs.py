"""An MLflow run's steps, from its opening to its status: what :class:`~spade.tracking.callback.RunRecord` calls.

* :func:`bind_experiment` opens the logger's run (a new one, or the resumed ``run_id``) safely under parallel jobs
  and tags its experiment (:mod:`~spade.tracking.experiment_tags`).
* :func:`log_run_config` records the parameters that describe the method (:mod:`~spade.tracking.params`), the
  whole config as ``config/train.yaml`` and the FID extractor's identity; :func:`record_process` tags the run with
  its host, process id and process start time while it runs (a resumed run is RUNNING again).
* :func:`describe_run` logs the datasets as inputs (:mod:`~spade.tracking.dataset_inputs`) and sets the
  description (:mod:`~spade.tracking.descriptions`); :func:`log_predictors` logs the classical baselines
  and the untrained model as child runs (:mod:`~spade.tracking.predictors`) and the run's report
  (:mod:`~spade.tracking.run_report`); :func:`drop_process_tags` removes the process tags of a run that finished.
* A run that does not finish is closed honestly: :func:`mark_run_ended` marks it KILLED (a signal, Ctrl+C:
  :func:`spade.utils.signals.install_signal_handlers`) or FAILED (any other exception), or deletes it when
  a refusal (a user error) came before it recorded any metric (:func:`refused_before_work`), and
  :func:`mark_stale_runs` (run by the next ``spade.train`` of the same row) marks RUNNING runs whose process is
  gone (a ``kill -9``, a power cut) KILLED, with a message. The process tags stay on a KILLED or FAILED run.

Only Lightning's public ``MLFlowLogger`` API is used (``experiment``: its ``MlflowClient``; ``run_id``;
``experiment_id``) and MLflow's own client. What a run has been through is in the store, and whether its run was
opened here in :data:`BOUND` (nothing is set on the logger).
"""

from __future__ import annotations

import datetime
import logging
import os
import signal
import socket
import time
import weakref
from dataclasses import dataclass
from collections.abc import Mapping
from typing import Any

from lightning.pytorch.loggers import Logger, MLFlowLogger
from lightning.pytorch.utilities import rank_zero_only
from omegaconf import DictConfig, OmegaConf

from spade.tracking.client import ensure_store, mlflow_client
from spade.tracking.dataset_inputs import DatasetUse, dataset_uses, log_dataset_inputs
from spade.tracking.descriptions import prerequisite_uses, run_description, what_it_is
from spade.tracking.experiment_tags import NOTE_TAG, ensure_experiment_tags
from spade.tracking.figure_tags import log_figure_tags
from spade.tracking.logged_model import LoggedStudent, describe_logged_model, model_note
from spade.tracking.logger import held_metrics
from spade.tracking.predictors import is_predictor_run, log_predictor_runs, predictors
from spade.utils.processes import pid_alive, process_start
from spade.tracking.links import artifact_url
from spade.tracking.progress_picture import epoch_series
from spade.tracking.run_report import CSV, MARKDOWN, REPORT_DIR, log_run_report
from spade.utils.errors import UserError
from spade.utils.signals import signal_received

log = logging.getLogger(__name__)


def mlflow_logger(loggers: list[Logger]) -> MLFlowLogger | None:
    """The run's MLflow logger among ``loggers`` (the first one); None when the run does not log to MLflow."""
    return next((lg for lg in loggers if isinstance(lg, MLFlowLogger)), None)


# -- opening the run --------------------------------------------------------------------------------------------
BOUND: weakref.WeakSet[Any] = weakref.WeakSet()
"""The loggers whose run :func:`bind_experiment` opened or resumed: from then on :func:`mark_run_ended` closes that
run when the run fails."""


def bind_experiment(ml: MLFlowLogger, cfg: DictConfig | None = None) -> None:
    """Open the logger's MLflow run (a new one in its experiment, or the resumed ``run_id``), safely under parallel
    jobs, and tag its experiment.

    Lightning's ``MLFlowLogger`` looks its experiment up and creates it when absent: two jobs of a sweep that
    start together into an empty store both find it absent and the second ``create_experiment`` fails. That
    failure leaves the logger unbound, so a second ``ml.experiment`` looks the experiment up again and finds the
    one the parallel job created (SPADE's logger, :mod:`~spade.tracking.logger`, does the same itself). The
    experiment gets :func:`~spade.tracking.experiment_tags.ensure_experiment_tags` (also one created before SPADE
    tagged experiments); a resumed run's experiment is tagged the same way. A deleted experiment of that name
    raises Lightning's error, as before.
    """
    from mlflow.exceptions import MlflowException

    try:
        client = ml.experiment
    except MlflowException:
        client = ml.experiment  # created meanwhile by a parallel job: this lookup finds it
    BOUND.add(ml)
    ensure_experiment_tags(client, client.get_experiment(ml.experiment_id), cfg)


def bound_run_id(ml: MLFlowLogger) -> str | None:
    """The logger's MLflow run id, without opening a run: on rank zero the run :func:`bind_experiment` opened or
    resumed (None before it did, or when it failed); on other ranks, whose logger holds no client, the ``run_id``
    it was made with (a resumed run; None for a new one)."""
    if rank_zero_only.rank == 0 and ml not in BOUND:
        return None
    return ml.run_id


def log_run_config(cfg: DictConfig, params: dict[str, Any], model: Any, ml: MLFlowLogger) -> None:
    """Log ``params``, the parameters that describe the method (:func:`~spade.tracking.params.run_params`: the
    config's groups), the whole composed config as ``config/train.yaml`` and the FID extractor's identity
    (tag ``fid_extractor``) into the logger's bound run."""
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


# -- the run's process and status -------------------------------------------------------------------------------
PROCESS_TAGS = ("spade.host", "spade.pid", "spade.proc_start")  # a RUNNING run's process (mark_stale_runs)


def process_tags() -> dict[str, str]:
    """This process as :data:`PROCESS_TAGS`: host name, process id and the process's start time (so that a
    recycled pid is not taken for this process). Set while a run is RUNNING; removed when it finishes
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


def end_status(exc: BaseException) -> tuple[str, str]:
    """(status, reason) of a run that ``exc`` ends: KILLED for a signal or Ctrl+C, FAILED otherwise."""
    sig = signal_received()
    killed = sig is not None or isinstance(exc, KeyboardInterrupt)
    reason = f"signal {signal.Signals(sig).name}" if sig is not None else f"{type(exc).__name__}: {exc}"
    return ("KILLED" if killed else "FAILED"), reason[:4000]


#: What :func:`mark_run_ended` returns for a refused run it deleted (not an MLflow status: the run is gone).
DELETED = "DELETED"


def refused_before_work(client: Any, run_id: str, exc: BaseException) -> bool:
    """Whether ``exc`` is a refusal (a :class:`~spade.utils.errors.UserError`: an empty test set, a full disk while
    a dataset was generated, a bad dataset) that came before the run ``run_id`` recorded any metric. Such a run
    holds nothing but its opening: it is deleted, not left FAILED (the one-line error says what to fix)."""
    if not isinstance(exc, UserError):
        return False
    try:
        return not client.get_run(run_id).data.metrics
    except Exception:  # noqa: BLE001 - unknown: keep the run, marked FAILED
        return False


def mark_run_ended(loggers: list[Logger], exc: BaseException) -> str | None:
    """Close this process's MLflow run after ``exc``: KILLED for a signal or Ctrl+C, FAILED otherwise, deleted
    (:data:`DELETED`) for a refusal before the run recorded anything (:func:`refused_before_work`); returns the
    status set (None when no run was open)."""
    ml = mlflow_logger(loggers)
    run_id = bound_run_id(ml) if ml is not None else None
    if run_id is None:
        return None  # no run was opened (or the one to resume could not be): nothing to close
    if refused_before_work(ml.experiment, run_id, exc):
        try:
            ml.experiment.delete_run(run_id)
            log.info("MLflow run %s deleted: refused before it recorded anything (%s)", run_id, str(exc)[:200])
            return DELETED
        except Exception as err:  # noqa: BLE001 - never hide the original error; the run is then marked FAILED
            log.warning("could not delete the refused MLflow run %s: %s", run_id, err)
    status, reason = end_status(exc)
    try:
        ml.experiment.set_tag(run_id, "spade.end_reason", reason)
        ml.experiment.set_terminated(run_id, status)
        log.info("MLflow run %s marked %s (%s)", run_id, status, reason[:200])
    except Exception as err:  # never hide the original error
        log.warning("could not mark MLflow run %s %s: %s", run_id, status, err)
    return status


def mark_opened_run_ended(loggers: list[Logger], exc: BaseException) -> str | None:
    """:func:`mark_run_ended` for a run Lightning opened before SPADE bound it (a run that failed in Lightning's
    setup, before its record's): Lightning's teardown marks an interrupted stage FAILED; a signal or Ctrl+C is
    KILLED. Returns the status set."""
    ml = mlflow_logger(loggers)
    if ml is None:
        return None
    if ml not in BOUND:
        try:
            ml.run_id  # the run Lightning opened (MLFlowLogger's public property)
        except Exception as err:  # noqa: BLE001 - never hide the original error
            log.warning("could not find the evaluation's MLflow run: %s", err)
            return None
        BOUND.add(ml)
    return mark_run_ended(loggers, exc)


def mark_stale_runs(cfg: DictConfig) -> list[str]:
    """Mark KILLED the RUNNING runs of this row (same MLflow experiment and run name) whose process is gone.

    A run's process is known by its ``spade.host`` / ``spade.pid`` / ``spade.proc_start`` tags; runs started on
    another host are left alone (their process cannot be checked from here) and named in the log. Returns one
    message per run marked.
    """
    logger_cfg = (cfg.get("logger") or {}).get("mlflow")
    if not logger_cfg or "MLFlowLogger" not in str(logger_cfg.get("_target_", "")):
        return []
    resolved = OmegaConf.to_container(logger_cfg, resolve=True)
    ensure_store(resolved.get("tracking_uri"))  # a fresh store's tables, created by one process at a time
    client = mlflow_client(resolved.get("tracking_uri"))
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


# -- describing the run ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class RunRef:
    """Where a finished run lives, for the closing lines of ``spade.train``."""

    tracking_uri: str
    experiment_id: str
    run_id: str
    run_name: str
    model_uri: str | None = None  # the student's MLflow Model logged on the run (runs:/RUN_ID/model), if any


def _picture_paths(client: Any, run_id: str) -> list[str]:
    """The run's pictures: the training-progress picture, then the prediction pictures."""
    try:
        root = sorted(a.path for a in client.list_artifacts(run_id) if a.path.endswith(".png"))
        return root + sorted(a.path for a in client.list_artifacts(run_id, "predictions") if a.path.endswith(".png"))
    except Exception:  # noqa: BLE001 - listing artifacts is a nicety of the description
        return []


def _references_note(metrics: dict[str, float], run: tuple[str, str]) -> str:
    """Where the run's references and report are (a run with test figures: :func:`log_predictors`, :func:`log_report`)."""
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


def run_figures(ml: MLFlowLogger) -> dict[str, float]:
    """The run's metrics with the references' figures its logger held back (:mod:`~spade.tracking.logger`)."""
    return {**dict(ml.experiment.get_run(ml.run_id).data.metrics), **held_metrics(ml)}


def describe_run(cfg: DictConfig, ml: MLFlowLogger, datamodule: Any, contexts: tuple[str, ...] | None = None,
                 logged_model: LoggedStudent | None = None) -> tuple[list[DatasetUse], dict[str, float], str, RunRef]:
    """Log the run's dataset inputs and set its description (with the MLflow Model logged on the run, when one
    was); returns (dataset uses, the run's metrics, the description, where the run lives)."""
    client, run_id = ml.experiment, ml.run_id
    uses = dataset_uses(datamodule) if datamodule is not None else []
    if contexts is not None:
        uses = [u for u in uses if u.context in contexts]
    try:
        log_dataset_inputs(client, run_id, uses)
    except (OSError, ValueError) as exc:  # an unreadable manifest: the run itself is fine, say so
        log.warning("datasets not logged as MLflow inputs: %s", exc)
    run = client.get_run(run_id)
    metrics = run_figures(ml)
    history = margin_history(client, run_id) if "margin/active" in metrics else None
    end = run.info.end_time or int(time.time() * 1000)
    seconds = (end - run.info.start_time) / 1000.0 if run.info.start_time else None
    description = run_description(cfg, metrics, uses, prerequisite_uses(cfg, client), _picture_paths(client, run_id),
                                  (str(run.info.experiment_id), run_id), history, seconds)
    description += _references_note(metrics, (str(run.info.experiment_id), run_id)) + model_note(logged_model)
    client.set_tag(run_id, NOTE_TAG, description)
    nicety("the runs view's figures", log_figure_tags, client, run_id, metrics)
    if logged_model is not None:
        nicety("the logged model's description", describe_logged_model, client, logged_model, cfg, metrics,
               (str(run.info.experiment_id), run_id, str(run.info.run_name)))
    ref = RunRef(str(client.tracking_uri), str(run.info.experiment_id), run_id, str(run.info.run_name),
                 logged_model.run_uri if logged_model is not None else None)
    return uses, metrics, description, ref


def margin_history(client: Any, run_id: str) -> list[tuple[int, float, float]]:
    """A guided student's margin activity per epoch, ``[(epoch, active, value)]``, from the run's ``margin/*``
    (logged at the global step of each epoch's validation, tag ``spade.margin_step=global``; older runs: step =
    epoch)."""
    series = epoch_series(client, run_id)
    values = dict(series.get("margin/value", []))
    return [(epoch, active, values.get(epoch, float("nan"))) for epoch, active in series.get("margin/active", [])]


def nicety(what: str, step: Any, *args: Any) -> Any:
    """Run one of the deliverables a finished run adds to its record; a failure is a warning, never the run's."""
    try:
        return step(*args)
    except Exception as exc:  # noqa: BLE001 - the run itself finished: its record must not fail it
        log.warning("%s not logged: %s", what, exc)
        return None


def log_predictors(tags: Mapping[str, Any], client: Any, run_id: str, test_uses: list[DatasetUse],
                   metrics: dict[str, float]) -> None:
    """The run's references as child runs (:mod:`~spade.tracking.predictors`), the run tagged with its role."""
    tags = dict(tags)
    nicety("predictor runs", log_predictor_runs, client, run_id, str(tags.get("role") or "model"), what_it_is(tags),
           test_uses, metrics)


def log_report(client: Any, run_id: str, run_name: str, role: str, description: str,
               metrics: dict[str, float]) -> None:
    """The run's report (:mod:`~spade.tracking.run_report`)."""
    nicety("run report", log_run_report, client, run_id, run_name, description, metrics, role)


def drop_process_tags(client: Any, run_id: str, finishing: bool = False) -> None:
    """Remove the process tags (:func:`process_tags`) and an empty ``spade.end_reason`` from a FINISHED run (or
    one ``finishing`` now: its record is complete and its logger closes it next): they identify a running run's
    process for :func:`mark_stale_runs` and mean nothing once it finished. A RUNNING run keeps them, and so does a
    KILLED or FAILED one (which process it was is part of what went wrong)."""
    run = client.get_run(run_id)
    if run.info.status != "FINISHED" and not (finishing and run.info.status == "RUNNING"):
        return
    tags = run.data.tags
    for key in (*PROCESS_TAGS, "spade.end_reason"):
        if key in tags and (key != "spade.end_reason" or not tags[key]):
            client.delete_tag(run_id, key)
