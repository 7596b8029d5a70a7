"""Models in the MLflow Model Registry under deterministic names tied to role, shape, size and data."""

from __future__ import annotations

import hashlib
import json
import logging
from pathlib import Path
from typing import Any

from lightning.pytorch.loggers import MLFlowLogger
from omegaconf import DictConfig, OmegaConf

log = logging.getLogger(__name__)


def data_fingerprint(cfg: DictConfig) -> str:
    """A short hash of what determines a run's training data (its generator configs and dataset paths)."""
    data = OmegaConf.to_container(cfg.data, resolve=True)
    keep = {k: data.get(k) for k in ("train_dir", "train_generate", "max_train_instances")}
    blob = json.dumps(keep, sort_keys=True, default=str).encode()
    return hashlib.sha256(blob).hexdigest()[:10]


def registry_name(cfg: DictConfig) -> str | None:
    """``<registry.prefix>-<data fingerprint>``, or None when the run registers nothing."""
    prefix = (cfg.get("registry") or {}).get("prefix")
    return f"{prefix}-{data_fingerprint(cfg)}" if prefix else None


def register_checkpoint(ml: MLFlowLogger, name: str, artifact_path: str, tags: dict[str, Any]) -> None:
    """Register the run's checkpoint artifact (a directory holding one .ckpt) as a new version of ``name``."""
    client = ml.experiment
    from mlflow.exceptions import MlflowException

    try:
        client.get_registered_model(name)
    except MlflowException:
        client.create_registered_model(name, tags={k: str(v) for k, v in tags.items()})
    source = f"{client.get_run(ml.run_id).info.artifact_uri}/{artifact_path}"
    version = client.create_model_version(
        name, source=source, run_id=ml.run_id, tags={"artifact_path": artifact_path, **{k: str(v) for k, v in tags.items()}}
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
