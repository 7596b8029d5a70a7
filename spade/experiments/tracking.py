"""What every run records in MLflow besides Lightning's metrics: config, tags, metric identities, checkpoints."""

from __future__ import annotations

import logging
from typing import Any

import lightning as L
from lightning.pytorch.loggers import Logger, MLFlowLogger
from lightning.pytorch.utilities import rank_zero_only
from omegaconf import DictConfig, OmegaConf

log = logging.getLogger(__name__)


def flatten(cfg: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested dict -> {"a/b/c": value}; lists are kept as their string form (MLflow params are strings)."""
    out: dict[str, Any] = {}
    for key, value in cfg.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            out.update(flatten(value, f"{name}/"))
        else:
            out[name] = value
    return out


def mlflow_logger(loggers: list[Logger]) -> MLFlowLogger | None:
    return next((lg for lg in loggers if isinstance(lg, MLFlowLogger)), None)


def bind_experiment(ml: MLFlowLogger) -> None:
    """Find or create the logger's MLflow experiment before the logger does, safely under parallel jobs.

    Lightning's ``MLFlowLogger`` looks its experiment up and creates it when absent: two jobs of a sweep that
    start together into an empty store both find it absent and the second ``create_experiment`` fails. Here a
    failed create falls back to the lookup. A table's experiment gets the table's description for the MLflow UI.
    """
    if ml._initialized or ml._run_id is not None or ml._experiment_id is not None:
        return  # resuming a run, or already bound
    from mlflow.exceptions import MlflowException

    from spade.experiments.tables import TABLES

    client, name = ml._mlflow_client, ml._experiment_name
    found = client.get_experiment_by_name(name)
    if found is not None:
        if found.lifecycle_stage != "deleted":
            ml._experiment_id = found.experiment_id
        return  # a deleted experiment: Lightning's own handling applies
    try:
        ml._experiment_id = client.create_experiment(name, artifact_location=ml._artifact_location)
    except MlflowException:
        found = client.get_experiment_by_name(name)  # created meanwhile by a parallel job
        if found is None:
            raise
        ml._experiment_id = found.experiment_id
        return
    table = next((t for t in TABLES.values() if t.experiment == name), None)
    if table is not None:
        client.set_experiment_tag(ml._experiment_id, "mlflow.note.content", table.describe())


@rank_zero_only  # under DDP, other ranks' MLflow loggers hold no run (their experiment is a no-op)
def start_run_logging(cfg: DictConfig, model: L.LightningModule, loggers: list[Logger]) -> None:
    """Log the composed config (flattened params and a YAML artifact) and the FID extractor's identity."""
    ml = mlflow_logger(loggers)
    if ml is None:
        return
    bind_experiment(ml)
    resolved = OmegaConf.to_container(cfg, resolve=True)
    params = {f"cfg/{k}": v for k, v in flatten(resolved).items() if not k.startswith("hydra")}
    fid = getattr(getattr(model, "test_metrics", None), "fid_identity", None)
    if fid:
        params["fid/extractor_identity"] = fid
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


@rank_zero_only
def finish_run(cfg: DictConfig, trainer: L.Trainer, model: L.LightningModule, loggers: list[Logger]) -> None:
    """Log the best and last checkpoints as artifacts and register the model when the config asks for it."""
    ml = mlflow_logger(loggers)
    if ml is None:
        return
    ckpt_cb = trainer.checkpoint_callback
    paths = {}
    if ckpt_cb is not None:
        if ckpt_cb.best_model_path:
            paths["best"] = ckpt_cb.best_model_path
        if getattr(ckpt_cb, "last_model_path", ""):
            paths["last"] = ckpt_cb.last_model_path
    for kind, path in paths.items():
        ml.experiment.log_artifact(ml.run_id, path, artifact_path=f"checkpoints/{kind}")
    from spade.experiments.registry import register_checkpoint, registry_name

    name = registry_name(cfg)
    if name and paths:
        tags = {**dict(cfg.get("tags") or {}), **dict((cfg.get("registry") or {}).get("tags") or {})}
        register_checkpoint(ml, name, f"checkpoints/{'best' if 'best' in paths else 'last'}", tags=tags)
