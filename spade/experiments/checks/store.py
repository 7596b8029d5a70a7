"""Checks of an MLflow store URI: an existing SQLite file is an MLflow store before MLflow opens (and would
write into) it."""

from __future__ import annotations

import sqlite3
from pathlib import Path
from urllib.parse import urlparse

from omegaconf import DictConfig

from spade.experiments.checks.values import _get, _unset
from spade.utils.errors import ConfigError


def _store_path(uri: str) -> Path | None:
    """The local path of an MLflow store URI (sqlite:///..., file:..., a plain path); None for a server."""
    if uri.startswith("sqlite:"):
        rest = uri[len("sqlite:"):]
        return Path(rest[3:] if rest.startswith("///") else rest.lstrip("/"))
    if uri.startswith("file:"):
        return Path(urlparse(uri).path)
    if "://" in uri:
        return None  # http(s), databricks, ...: the server answers for itself
    return Path(uri)


def check_store_file(key: str, uri: str) -> None:
    """An existing SQLite store at ``uri`` must be an MLflow store: read-only, before MLflow opens it (MLflow
    creates its tables in any SQLite file it is given, so a reader would write into someone else's database)."""
    path = _store_path(uri)
    if path is None or not uri.startswith("sqlite:") or not path.is_file():
        return
    try:
        db = sqlite3.connect(f"file:{path}?mode=ro", uri=True, timeout=30)
        try:
            tables = {row[0] for row in db.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
        finally:
            db.close()
    except sqlite3.DatabaseError as exc:
        raise ConfigError(f"{key}={uri}: {path} is not an SQLite database ({exc}); point {key} (or SPADE_HOME / "
                          "MLFLOW_TRACKING_URI) at the MLflow store the runs were logged to") from None
    missing = {"experiments", "runs", "metrics", "alembic_version"} - tables
    if missing:
        raise ConfigError(f"{key}={uri}: {path} is an SQLite database but not an MLflow store (no "
                          f"{', '.join(sorted(missing))} table); it is left untouched. Point {key} (or SPADE_HOME / "
                          "MLFLOW_TRACKING_URI) at the MLflow store the runs were logged to")


def _check_logger_store(cfg: DictConfig) -> None:
    """The store a run logs to, when it is an existing SQLite file, must be an MLflow store
    (:func:`check_store_file`): someone else's database is never written."""
    uri = _get(cfg, "logger.mlflow.tracking_uri")
    if not _unset(uri):
        check_store_file("logger.mlflow.tracking_uri", str(uri))
