"""Models in the MLflow Model Registry under deterministic names tied to role, shape, size and data.

Which version a run uses is pinned, not "the newest": the first version registered under a name gets the alias
``champion`` (:data:`~spade.tracking.client.CHAMPION_ALIAS`), and a run that needs that model resolves the alias
(or an exact version its config names). Registering another version later does not move the alias unless asked (``registry.promote=true``),
so re-running a student row after another expert was trained uses the same expert.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lightning.pytorch.loggers import MLFlowLogger
from omegaconf import DictConfig, OmegaConf

from spade.data.fingerprint import fingerprint
from spade.tracking.client import CHAMPION_ALIAS, ensure_store, mlflow_client

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class RegisteredCheckpoint:
    """One registered model version, downloaded: what a run that used it records."""

    name: str
    version: int
    run_id: str
    path: Path

    def describe(self) -> str:
        return f"{self.name} v{self.version} (run {self.run_id})"


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
                        version_description: str | None = None, promote: bool = False) -> int:
    """Register the run's checkpoint artifact (a directory holding one .ckpt) as a new version of ``name``; return
    its version number.

    The registered model carries ``description`` and the ``data_fingerprint`` tag (its name ends in it); an
    older registration without them gets them. Each version carries the same tags and ``version_description``.
    The new version becomes the :data:`CHAMPION_ALIAS` when the name has none yet or when ``promote``.
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
    aliases = (model.aliases if model is not None else None) or {}
    if promote or CHAMPION_ALIAS not in aliases:
        client.set_registered_model_alias(name, CHAMPION_ALIAS, version.version)
        log.info("%s@%s is version %s", name, CHAMPION_ALIAS, version.version)
    return int(version.version)


def resolve_version(client: Any, name: str, version: str | int = CHAMPION_ALIAS) -> Any | None:
    """The ModelVersion of ``name`` that ``version`` names: an alias (default :data:`CHAMPION_ALIAS`), a version
    number, or ``latest`` (the newest, unpinned). None when ``name`` is not registered. A name registered before aliases
    existed has no champion: its newest version is made the champion now, so that it stays the one used."""
    from mlflow.exceptions import MlflowException

    try:
        versions = client.search_model_versions(f"name='{name}'")
    except MlflowException:
        return None
    if not versions:
        return None
    if str(version) == "latest":
        return max(versions, key=lambda v: int(v.version))
    if str(version).isdigit():
        found = [v for v in versions if int(v.version) == int(version)]
        if not found:
            raise ValueError(f"registered model {name} has no version {version}; its versions are "
                             f"{sorted(int(v.version) for v in versions)} (or use the alias {CHAMPION_ALIAS} / latest)")
        return found[0]
    try:
        return client.get_model_version_by_alias(name, str(version))
    except MlflowException:
        if str(version) != CHAMPION_ALIAS:
            raise ValueError(f"registered model {name} has no alias @{version}; set one in the MLflow UI or name a "
                             f"version number (requires.<key>.version=N)") from None
    newest = max(versions, key=lambda v: int(v.version))
    client.set_registered_model_alias(name, CHAMPION_ALIAS, newest.version)
    log.info("%s had no @%s: pinned its newest version %s", name, CHAMPION_ALIAS, newest.version)
    return newest


def fetch_registered(tracking_uri: str, name: str, cache_dir: str | Path,
                     version: str | int = CHAMPION_ALIAS) -> RegisteredCheckpoint | None:
    """Download the version of registered model ``name`` that ``version`` names (:func:`resolve_version`); None
    when ``name`` is not registered."""
    ensure_store(tracking_uri)  # a fresh store's tables, created by one process at a time
    client = mlflow_client(tracking_uri)
    chosen = resolve_version(client, name, version)
    if chosen is None:
        return None
    dst = Path(cache_dir) / name / f"v{chosen.version}"
    ckpts = sorted(dst.rglob("*.ckpt")) if dst.is_dir() else []
    if not ckpts:
        dst.mkdir(parents=True, exist_ok=True)
        artifact_path = (chosen.tags or {}).get("artifact_path", "checkpoints/best")
        client.download_artifacts(chosen.run_id, artifact_path, str(dst))
        ckpts = sorted(dst.rglob("*.ckpt"))
    if not ckpts:
        raise FileNotFoundError(f"registered model {name} v{chosen.version} holds no .ckpt under {dst}")
    return RegisteredCheckpoint(name, int(chosen.version), str(chosen.run_id), ckpts[0])
