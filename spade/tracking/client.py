"""The one way SPADE opens an MLflow store: :func:`mlflow_client` (defined in :mod:`spade.deploy.mlflow_models`, the
lowest package that opens a store, and re-exported here), and the registry alias a run resolves by default.

A local SQLite store is created by the first client that opens it (MLflow runs its schema migrations then), and two
processes doing so at once collide (``duplicate column name``): :func:`ensure_store` opens a fresh store under
:func:`store_lock`, so that two ``spade.train`` started together on an empty store both run.
"""

from __future__ import annotations

import contextlib
import fcntl
from collections.abc import Iterator

from spade.deploy.mlflow_models import DEFAULT_ALIAS, mlflow_client

__all__ = ["CHAMPION_ALIAS", "ensure_store", "mlflow_client", "store_lock"]

CHAMPION_ALIAS = DEFAULT_ALIAS
"""The registry alias a prerequisite resolves by default (``requires.<key>.version``) and that the first version
registered under a name gets; the same alias ``spade.export register=NAME`` points at its version."""


@contextlib.contextmanager
def store_lock(tracking_uri: str | None) -> Iterator[None]:
    """An exclusive ``fcntl`` lock on ``<store>.lock`` beside a local SQLite store (nothing for a server or a file
    store): the processes of SPADE that open one store take turns while MLflow creates its tables."""
    from spade.config.store_checks import store_path

    uri = str(tracking_uri or "")
    path = store_path(uri) if uri.startswith("sqlite:") else None
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
    """Open the store at ``tracking_uri`` once, creating a fresh SQLite store's tables under :func:`store_lock`
    (nothing for another kind of store). A store that cannot be opened is left to the run's logger to report."""
    if not tracking_uri or not str(tracking_uri).startswith("sqlite:"):
        return
    with store_lock(tracking_uri):
        mlflow_client(tracking_uri).search_experiments(max_results=1)
