"""A student run's deliverable on its own run: the best checkpoint as an MLflow Model.

:func:`log_student_model` exports the checkpoint to ONNX (:func:`spade.deploy.export.export_student`, checked
against PyTorch) and logs it as an MLflow Model named ``model`` on the training run
(:func:`spade.deploy.mlflow_models.log_onnx_student`: ONNX flavour, signature ``state`` float32 (-1, 3, H, W) ->
``logits`` float32 (-1, 1, H, W), SPADE's window metadata, the flavour's pip requirements). MLflow's runs table
shows it in the Models column and ``python -m spade.plan model=runs:/RUN_ID/model`` plans with it. Nothing is
registered here: a registered name is the job of ``python -m spade.export register=NAME`` (or the row's
``registry`` settings). Experts, and runs without an MLflow run, log no model.
"""

from __future__ import annotations

import logging
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf
from spade.deploy.mlflow_models import MODEL_NAME, log_onnx_student, using_tracking_uri
from spade.tracking.experiment_tags import NOTE_TAG
from spade.tracking.links import relative_run_link

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class LoggedStudent:
    """The model logged on a run: ``runs:/RUN_ID/model`` and MLflow's own id of it (``models:/m-...``)."""

    run_uri: str
    model_uri: str
    seconds: float  # export, parity check and logging together


def is_student_run(cfg: DictConfig) -> bool:
    """Whether ``cfg`` trains a student (``StudentModule``): the runs whose checkpoint is a deployable model."""
    return str(OmegaConf.select(cfg, "model._target_", default="") or "").endswith("StudentModule")


def log_student_model(tracking_uri: str, run_id: str, checkpoint: str | Path) -> LoggedStudent:
    """Export ``checkpoint`` (a student's) to ONNX in a temporary folder and log it as the MLflow Model ``model`` of
    run ``run_id`` in the store at ``tracking_uri`` (not registered). Raises what the export or MLflow raises."""
    from spade.deploy.export import export_student
    start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="spade-model-") as folder:
        # parity on a batch of 2 (another size than the exported 1); no latency runs: the run's time is not spent
        report = export_student(checkpoint, Path(folder) / "student.onnx", "onnx", parity_batch=2, latency_runs=0)
        with using_tracking_uri(tracking_uri):
            info = log_onnx_student(report.out_path, run_id, name=MODEL_NAME)
    return LoggedStudent(f"runs:/{run_id}/{MODEL_NAME}", str(info.model_uri), time.perf_counter() - start)


def try_log_student_model(cfg: DictConfig, tracking_uri: str, run_id: str, checkpoint: str | None
                          ) -> LoggedStudent | None:
    """:func:`log_student_model` for a student run with a checkpoint; None for an expert or without one. A failure
    (an export that does not reproduce the checkpoint, a store that refuses the model) is one warning line: the
    run itself finished and keeps its checkpoints."""
    if not checkpoint or not is_student_run(cfg):
        return None
    try:
        logged = log_student_model(tracking_uri, run_id, checkpoint)
    except Exception as exc:  # noqa: BLE001 - the run finished: its deliverable's failure must not fail it
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
        log.warning("the student's MLflow Model was not logged on run %s (%s: %s); python -m spade.export "
                    "ckpt_path=%s register=NAME logs it in a run of its own", run_id, type(exc).__name__, first,
                    checkpoint)
        return None
    log.info("logged the student as %s (%s) in %.1f s", logged.run_uri, logged.model_uri, logged.seconds)
    return logged


def model_note(logged: Any) -> str:
    """The description's paragraph on the logged model: its URIs and the command that plans with it."""
    if logged is None:
        return ""
    return (f"\n\nModel: the best checkpoint as an MLflow Model (ONNX), `{logged.run_uri}` (`{logged.model_uri}`): "
            f"`python -m spade.plan MAP.yaml start=X,Y,YAW goal=X,Y model={logged.run_uri}`.")


def logged_model_description(cfg: DictConfig, metrics: dict[str, float], run: tuple[str, str, str],
                             run_uri: str) -> str:
    """The logged model's description (its page in the MLflow UI): what it is, the run that trained it (linked),
    its test figures (the trained student's own, :func:`~spade.tracking.descriptions.figures_table`
    without the references: those are the run's child runs) and how to plan with it."""
    from spade.tracking.descriptions import FIGURES, figures_table, what_it_is
    experiment_id, run_id, run_name = run
    own = {k: v for k, v in metrics.items() if k.startswith("test/") and not k.startswith("test/baseline/")}
    table = figures_table({k: v for k, v in own.items() if k[len("test/"):] in FIGURES})
    tags = dict(cfg.get("tags") or {})
    text = (f"The best checkpoint of run [{run_name}]({relative_run_link(experiment_id, run_id)}) "
            f"({what_it_is(tags)}, {tags.get('shape', '?')}-shape paths, scale `{tags.get('scale', '?')}`) as ONNX. "
            f"Its metrics are its test figures on the run's test set; the baselines and the untrained model it was "
            f"compared with are the run's child runs. Plan with it: `python -m spade.plan MAP.yaml start=X,Y,YAW "
            f"goal=X,Y model={run_uri}`.")
    return (table.split("\n\n", 1)[0] + "\n\n" + text) if table else text


def describe_logged_model(client: Any, logged: LoggedStudent, cfg: DictConfig, metrics: dict[str, float],
                          run: tuple[str, str, str]) -> None:
    """Set the logged model's description (tag ``mlflow.note.content``: :func:`logged_model_description`)."""
    model_id = logged.model_uri.split("/")[-1] if logged.model_uri.startswith("models:/") else logged.model_uri
    client.set_logged_model_tags(model_id, {NOTE_TAG: logged_model_description(cfg, metrics, run, logged.run_uri)})
