"""``spade.report``'s checks: the table exists and the MLflow store is there."""

from __future__ import annotations

from pathlib import Path

from omegaconf import DictConfig

from spade.experiments.checks.store import _store_path, check_store_file
from spade.experiments.checks.values import _get, _unset
from spade.experiments.tables import get_table
from spade.utils.errors import ConfigError


def validate_report_config(cfg: DictConfig) -> None:
    """``spade.report``'s checks: the table exists and the MLflow store is there (a missing one would be created
    empty and every row reported missing)."""
    table = _get(cfg, "table")
    if str(table) not in ("all", "closed_loop"):  # closed_loop: spade.experiments.closed_loop_table
        try:
            get_table(table)
        except (KeyError, ValueError) as exc:
            raise ConfigError(f"table={table}: {exc.args[0] if exc.args else exc}") from None
    uri = _get(cfg, "tracking_uri")
    if _unset(uri):
        raise ConfigError("tracking_uri is not set; pass tracking_uri=sqlite:///PATH/logs/mlflow.db")
    path = _store_path(str(uri))
    if path is not None and not path.exists():
        raise ConfigError(f"tracking_uri={uri}: there is no MLflow store at {path} (reporting would create an empty "
                          "one); point tracking_uri (or SPADE_HOME / MLFLOW_TRACKING_URI) at the store the runs were "
                          "logged to")
    if path is not None and str(uri).startswith("sqlite:") and path.is_dir():
        raise ConfigError(f"tracking_uri={uri}: {path} is a directory, not an MLflow SQLite store; point it at the "
                          "store file, e.g. sqlite:///PATH/logs/mlflow.db")
    check_store_file("tracking_uri", str(uri))
    out = _get(cfg, "output_dir")
    if not _unset(out) and Path(str(out)).is_file():
        raise ConfigError(f"output_dir={out} is a file; give a folder for the report files")
