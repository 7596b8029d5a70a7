"""Models in the MLflow Model Registry under deterministic names tied to role, shape, size and data."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

from lightning.pytorch.loggers import MLFlowLogger
from omegaconf import DictConfig, OmegaConf

from spade.data.fingerprint import fingerprint

log = logging.getLogger(__name__)


def data_fingerprint(cfg: DictConfig) -> str:
    """A short hash of what determines a run's training data (its generator configs and dataset paths): the data
    part of a registered model's name, known before the data exists (:func:`spade.data.fingerprint.fingerprint`)."""
    data = OmegaConf.to_container(cfg.data, resolve=True)
    return fingerprint({k: data.get(k) for k in ("train_dir", "train_generate", "max_train_instances")})


def registry_name(cfg: DictConfig) -> str | None:
    """``<registry.prefix>-<data fingerprint>``, or None when the run registers nothing."""
    prefix = (cfg.get("registry") or {}).get("prefix")
    return f"{prefix}-{data_fingerprint(cfg)}" if prefix else None


def register_checkpoint(ml: MLFlowLogger, name: str, artifact_path: str, tags: dict[str, Any],
                        data_fingerprint: str | None = None, description: str | None = None,
                        version_description: str | None = None) -> None:
    """Register the run's checkpoint artifact (a directory holding one .ckpt) as a new version of ``name``.

    The registered model carries ``description`` and the ``data_fingerprint`` tag (its name ends in it); an
    older registration without them gets them. Each version carries the same tags and ``version_description``.
    """
    client = ml.experiment
    from mlflow.exceptions import MlflowException

    tags = {k: str(v) for k, v in tags.items()}
    if data_fingerprint:
        tags["data_fingerprint"] = str(data_fingerprint)
    try:
        model = client.get_registered_model(name)
    except MlflowException:
        try:
            client.create_registered_model(name, tags=tags, description=description)
        except MlflowException:  # registered meanwhile by a parallel job
            model = client.get_registered_model(name)
        else:
            model = None
    if model is not None:
        if description and not model.description:
            client.update_registered_model(name, description=description)
        if data_fingerprint and (model.tags or {}).get("data_fingerprint") != str(data_fingerprint):
            client.set_registered_model_tag(name, "data_fingerprint", str(data_fingerprint))
    source = f"{client.get_run(ml.run_id).info.artifact_uri}/{artifact_path}"
    version = client.create_model_version(
        name, source=source, run_id=ml.run_id, tags={"artifact_path": artifact_path, **tags},
        description=version_description,
    )
    log.info("Registered %s version %s from run %s", name, version.version, ml.run_id)


def fetch_checkpoint(tracking_uri: str, name: str, cache_dir: str | Path) -> Path | None:
    """Download the newest version of registered model ``name``; None when it is not registered."""
    from mlflow import MlflowClient
    from mlflow.exceptions import MlflowException

    client = MlflowClient(tracking_uri=tracking_uri)
    try:
        versions = client.search_model_versions(f"name='{name}'")
    except MlflowException:
        return None
    if not versions:
        return None
    newest = max(versions, key=lambda v: int(v.version))
    dst = Path(cache_dir) / name / f"v{newest.version}"
    ckpts = sorted(dst.rglob("*.ckpt")) if dst.is_dir() else []
    if not ckpts:
        dst.mkdir(parents=True, exist_ok=True)
        artifact_path = newest.tags.get("artifact_path", "checkpoints/best")
        client.download_artifacts(newest.run_id, artifact_path, str(dst))
        ckpts = sorted(dst.rglob("*.ckpt"))
    if not ckpts:
        raise FileNotFoundError(f"registered model {name} v{newest.version} holds no .ckpt under {dst}")
    return ckpts[0]
