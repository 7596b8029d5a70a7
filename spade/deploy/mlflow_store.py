"""A local MLflow store made safely: where its file lies (:func:`store_path`), the lock its users take
(:func:`store_lock`), its creation (:func:`ensure_store`) and what is wrong with a store that cannot be opened
(:func:`store_problem`).

MLflow creates a new SQLite store's tables (and runs its schema migrations) the first time a client opens it. Two
processes doing so at once collide (``table ... already exists``, ``duplicate column name``), and a creation stopped
half-way (Ctrl+C) left a store on which every later command failed. So every SPADE path that may create a store
(training, evaluation, the critic's logger, ``spade.export register=``, ``spade.closed_loop``) calls
:func:`ensure_store` first: under an exclusive lock on ``<store>.lock`` it checks an existing store, or creates a
missing one in a temporary file beside it and moves that into place (one ``rename(2)``) once MLflow's schema is
complete. A store is thus absent or complete, never half-made.

This module sits in :mod:`spade.deploy` beside :mod:`spade.deploy.mlflow_models`, the lowest package that opens a
store (``export register=`` and model URIs); :mod:`spade.tracking.client` re-exports it.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import secrets
import socket
import sqlite3
from collections.abc import Iterator
from pathlib import Path
from typing import Any
from urllib.parse import urlparse

from spade.utils.errors import ConfigError

__all__ = ["StoreError", "ensure_store", "foreign_file_problem", "mlflow_client", "sqlite_store_path", "store_lock",
           "store_path", "store_problem"]

#: The tables every MLflow store has: an SQLite file without them is not (or not yet) an MLflow store.
CORE_TABLES = frozenset({"experiments", "runs", "metrics", "alembic_version"})


class StoreError(ConfigError):
    """An existing SQLite store that cannot be used as it is (half-made, or of another MLflow schema); the message
    names it and the fix (a user error: one line, exit status 2)."""


def mlflow_client(tracking_uri: str | None = None) -> Any:
    """An ``MlflowClient`` on the store at ``tracking_uri`` (MLflow's current store when None): the one place SPADE
    builds one (:mod:`spade.tracking.client` re-exports it)."""
    from mlflow import MlflowClient

    return MlflowClient(tracking_uri=str(tracking_uri) if tracking_uri else None)


def store_path(uri: str) -> Path | None:
    """The local path of an MLflow store URI (sqlite:///..., file:..., a plain path); None for a server."""
    if uri.startswith("sqlite:"):
        rest = uri[len("sqlite:"):]
        return Path(rest[3:] if rest.startswith("///") else rest.lstrip("/"))
    if uri.startswith("file:"):
        return Path(urlparse(uri).path)
    if "://" in uri:
        return None  # http(s), databricks, ...: the server answers for itself
    return Path(uri)


def sqlite_store_path(tracking_uri: str | None) -> Path | None:
    """The file of a local SQLite store URI; None for any other store (a server, a file store) or no URI."""
    uri = str(tracking_uri or "")
    return store_path(uri) if uri.startswith("sqlite:") else None


@contextlib.contextmanager
def store_lock(tracking_uri: str | None) -> Iterator[None]:
    """An exclusive ``fcntl`` lock on ``<store>.lock`` beside a local SQLite store (nothing for a server or a file
    store): the processes of SPADE that open one store take turns while it is checked or created."""
    path = sqlite_store_path(tracking_uri)
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


def _read_only(path: Path) -> sqlite3.Connection:
    """The SQLite file ``path`` opened read-only (``mode=ro``): a check never writes into the file it checks."""
    return sqlite3.connect(f"file:{path}?mode=ro", uri=True, timeout=30)


def _tables(db: sqlite3.Connection) -> set[str]:
    return {row[0] for row in db.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}


def foreign_file_problem(path: Path) -> str | None:
    """Why the existing, non-empty file ``path`` is no MLflow store (not SQLite, or SQLite without MLflow's core
    tables), read-only and before MLflow opens it (MLflow creates its tables in any SQLite file it is given); None
    for a missing or empty file or an MLflow store."""
    if not path.is_file() or path.stat().st_size == 0:
        return None
    try:
        db = _read_only(path)
        try:
            tables = _tables(db)
        finally:
            db.close()
    except sqlite3.DatabaseError as exc:
        return f"{path} is not an SQLite database ({exc})"
    missing = CORE_TABLES - tables
    if missing:
        return (f"{path} is an SQLite database but not an MLflow store (no {', '.join(sorted(missing))} table); it is "
                "left untouched")
    return None


def _schema_head() -> str | None:
    """The schema revision this MLflow creates (None when MLflow does not say: the revision is then not checked)."""
    try:
        from mlflow.store.db.utils import _get_latest_schema_revision  # MLflow's own, private: guarded

        return str(_get_latest_schema_revision())
    except Exception:  # noqa: BLE001 - another MLflow version: skip the revision check, MLflow's open still checks
        return None


def store_problem(path: Path) -> str | None:
    """What keeps the existing SQLite file ``path`` from being used as an MLflow store, with the fix; None when it
    is a complete store (or not an MLflow store at all: :func:`spade.config.store_checks.check_store_file` refuses
    that). Read-only: the file is opened with ``mode=ro`` and never written.

    A *half-made* store (some of MLflow's tables, or all of them at a schema revision other than this MLflow's, and
    no run) is what a creation stopped half-way by an older SPADE left; deleting it loses nothing. A store of
    another MLflow version with runs is upgraded with ``mlflow db upgrade``."""
    if not path.is_file() or path.stat().st_size == 0:
        return None
    try:
        db = _read_only(path)
        try:
            tables = _tables(db)
            if not tables & CORE_TABLES:
                return None  # not an MLflow store: the store check says so
            revision = (db.execute("SELECT version_num FROM alembic_version").fetchone() or [None])[0] \
                if "alembic_version" in tables else None
            runs = db.execute("SELECT COUNT(*) FROM runs").fetchone()[0] if "runs" in tables else 0
        finally:
            db.close()
    except sqlite3.DatabaseError:
        return None  # not an SQLite database: the store check says so
    head = _schema_head()
    complete = CORE_TABLES <= tables and revision is not None and (head is None or revision == head)
    if complete:
        return None
    if not runs:
        return (f"{path} is a half-made MLflow store (its creation was interrupted: schema revision {revision}, "
                f"{len(tables & CORE_TABLES)} of MLflow's core tables) and holds no run; delete it (rm {path}) "
                "and run the command again, which creates the store afresh")
    return (f"{path} is an MLflow store of another MLflow version (schema revision {revision}, this MLflow's is "
            f"{head}) holding {runs} runs; back it up, then upgrade it with `mlflow db upgrade sqlite:///{path}` "
            "(or point MLFLOW_TRACKING_URI at another store)")


def _stale_partials(path: Path) -> list[Path]:
    """The temporary files of creations that never finished (a ``kill -9`` mid-creation): removed by the next one."""
    return sorted(path.parent.glob(f".{path.name}.partial-*"))


def _dispose(uri: str) -> None:
    """Close MLflow's cached connections to the temporary store before it is moved (best effort: private API)."""
    with contextlib.suppress(Exception):
        from mlflow.store.tracking.sqlalchemy_store import SqlAlchemyStore

        engine: Any = SqlAlchemyStore._engine_map.pop(uri, None)
        if engine is not None:
            engine.dispose()


def _create(path: Path) -> None:
    """Create a complete MLflow store at ``path``: made in a temporary file beside it (MLflow creates its tables
    and the Default experiment there) and moved into place in one ``os.replace``. Interrupted (Ctrl+C, an error),
    the temporary file is removed and nothing is at ``path``."""
    for stale in _stale_partials(path):
        stale.unlink(missing_ok=True)  # under the lock: no other creation is running
    tmp = path.with_name(f".{path.name}.partial-{socket.gethostname()}-{os.getpid()}-{secrets.token_hex(4)}")
    uri = f"sqlite:///{tmp}"
    try:
        mlflow_client(uri).search_experiments(max_results=1)  # MLflow makes its schema and the Default experiment
        _dispose(uri)
        os.replace(tmp, path)
    finally:
        _dispose(uri)
        for leftover in (tmp, tmp.with_name(tmp.name + "-journal")):
            leftover.unlink(missing_ok=True)


def ensure_store(tracking_uri: str | None) -> None:
    """Make the local SQLite store at ``tracking_uri`` ready under :func:`store_lock` (nothing for another kind of
    store): a missing (or empty) file is created complete (:func:`_create`); an existing one is checked
    (:func:`store_problem`) and a half-made one or one of another schema refused, named, with the fix."""
    path = sqlite_store_path(tracking_uri)
    if path is None:
        return
    with store_lock(tracking_uri):
        if path.is_file() and path.stat().st_size > 0:
            problem = store_problem(path)
            if problem:
                raise StoreError(problem)
            return
        _create(path)
