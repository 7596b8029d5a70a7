"""The one way SPADE opens an MLflow store: :func:`mlflow_client` (defined in :mod:`spade.deploy.mlflow_store`, the
lowest package that opens a store, and re-exported here), and the registry alias a run resolves by default.

A local SQLite store is created by the first client that opens it (MLflow runs its schema migrations then), and two
processes doing so at once collide (``duplicate column name``, ``table ... already exists``); a creation stopped
half-way left a store every later command failed on. :func:`ensure_store` (of :mod:`spade.deploy.mlflow_store`,
re-exported here with :func:`store_lock`) checks or creates the store under the store's lock, a new one in a
temporary file moved into place once complete: every path that may create a store calls it before opening one.
"""

from __future__ import annotations

from spade.deploy.mlflow_models import DEFAULT_ALIAS
from spade.deploy.mlflow_store import ensure_store, mlflow_client, store_lock

__all__ = ["CHAMPION_ALIAS", "ensure_store", "mlflow_client", "store_lock"]

CHAMPION_ALIAS = DEFAULT_ALIAS
"""The registry alias a prerequisite resolves by default (``requires.<key>.version``) and that the first version
registered under a name gets; the same alias ``spade.export register=NAME`` points at its version."""
