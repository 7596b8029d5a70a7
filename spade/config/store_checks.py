"""Checks of an MLflow store URI: an existing SQLite file is a complete MLflow store before MLflow opens (and would
write into) it. Where a store URI points (:func:`store_path`) is :mod:`spade.deploy.mlflow_store`'s, re-exported."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

from omegaconf import DictConfig

from spade.config.options import read_options
from spade.deploy.mlflow_store import foreign_file_problem, store_path, store_problem
from spade.utils.errors import ConfigError
from spade.utils.option_checks import unset


def check_store_file(key: str, uri: str) -> None:
    """An existing SQLite store at ``uri`` must be an MLflow store: read-only, before MLflow opens it (MLflow
    creates its tables in any SQLite file it is given, so a reader would write into someone else's database)."""
    path = store_path(uri)
    if path is None or not uri.startswith("sqlite:"):
        return  # a server answers for itself
    problem = store_problem(path)
    if problem:  # a half-made store (a creation interrupted by an older SPADE), or another MLflow's schema
        raise ConfigError(f"{key}={uri}: {problem}")
    foreign = foreign_file_problem(path)
    if foreign:
        raise ConfigError(f"{key}={uri}: {foreign}; point {key} (or SPADE_HOME / MLFLOW_TRACKING_URI) at the MLflow "
                          "store the runs were logged to")


#: Seconds a tracking server has to answer the check's one request (MLflow's own client would retry for minutes).
SERVER_TIMEOUT_S = 5.0


def check_server(key: str, uri: str, timeout: float = SERVER_TIMEOUT_S) -> None:
    """An ``http(s)://`` tracking URI must answer, checked with one request of ``timeout`` seconds before any work:
    MLflow's client retries an unreachable server with back-off (``MLFLOW_HTTP_REQUEST_MAX_RETRIES``, 7 by default,
    ``MLFLOW_HTTP_REQUEST_TIMEOUT`` 120 s each), so a wrong port failed after minutes, with a traceback. Any HTTP
    answer (even 401 or 404: a proxy, a server with authentication) counts as reachable; MLflow's own errors then
    speak for it."""
    import urllib.error
    import urllib.request

    if not uri.startswith(("http://", "https://")):
        return
    url = uri.rstrip("/") + "/health"
    try:
        with urllib.request.urlopen(urllib.request.Request(url, method="GET"), timeout=timeout):  # noqa: S310
            return
    except urllib.error.HTTPError:
        return  # it answered
    except (urllib.error.URLError, OSError, ValueError) as exc:
        reason = getattr(exc, "reason", exc)
        raise ConfigError(f"{key}={uri}: no tracking server answers there within {timeout:g} s ({reason}); start it "
                          f"(mlflow server --port PORT) or point {key} (or SPADE_HOME / MLFLOW_TRACKING_URI) at a "
                          "reachable server or a sqlite:/// store") from None


@dataclass(frozen=True)
class StoreOptions:
    """The MLflow store a run logs to (``logger.mlflow``; unset with ``logger=none``: nothing is logged)."""

    node: ClassVar[str] = "logger.mlflow"

    tracking_uri: Any = None

    @property
    def uri(self) -> str | None:
        return None if unset(self.tracking_uri) else str(self.tracking_uri)


def check_store(store: StoreOptions) -> None:
    """The store a run logs to, when it is an existing SQLite file, must be an MLflow store
    (:func:`check_store_file`): someone else's database is never written; a tracking server must answer
    (:func:`check_server`)."""
    if store.uri is not None:
        check_store_file("logger.mlflow.tracking_uri", store.uri)
        check_server("logger.mlflow.tracking_uri", store.uri)


def check_logger_store(cfg: DictConfig) -> StoreOptions:
    """:func:`check_store` of a command's config (for the checks that take the config)."""
    store = read_options(cfg, StoreOptions)
    check_store(store)
    return store
