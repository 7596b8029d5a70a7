"""``spade.report``'s checks: the table exists, the MLflow store is there, and the pages it writes replace only
earlier pages of SPADE's, with ``overwrite=true``."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from omegaconf import DictConfig

from spade.deploy.outputs import replace_refusal
from spade.config.file_checks import check_path_value, check_paths, check_writable
from spade.config.store_checks import store_path, check_server, check_store_file
from spade.config.values import check_bool, get
from spade.utils.errors import ConfigError
from spade.utils.option_checks import MISSING, unset


def report_files(table: Any, chart: bool = True, teacher_page: Any = None) -> list[str]:
    """The names of the files ``spade.report`` writes into ``output_dir`` for ``table`` (one table, ``all`` or
    ``closed_loop``), as :func:`spade.experiments.reporting.build.build_report` and
    :func:`spade.experiments.closed_loop_table.closed_loop_report` name them (a table without comparisons writes
    no ``_comparisons.csv``: listed anyway, an existing one is not replaced unasked either)."""
    if str(table) == "closed_loop":
        return ["closed_loop.md", "closed_loop.csv"]
    if str(table) == "oracle":
        return ["oracle.md", "oracle_curve.png"]
    if str(table) == "teacher":
        from spade.experiments.teacher_table import teacher_files

        return list(teacher_files(teacher_page))
    from spade.experiments.tables import TABLES, get_table  # the report's own tables, for spade.report alone

    tables = list(TABLES.values()) if str(table) == "all" else [get_table(table)]
    return [name for t in tables
            for name in (f"{t.key}.md", f"{t.key}.csv", f"{t.key}_comparisons.csv", *([f"{t.key}.png"] if chart else []))]


def _check_output_dir(cfg: DictConfig) -> None:
    """``output_dir`` (null: print only) is a folder path, neither empty nor the root, and none of the pages the
    report would write there exists unless SPADE wrote it and ``overwrite=true``: refused before any run is read."""
    out = get(cfg, "output_dir")
    if out is MISSING or out is None:
        return
    check_path_value("output_dir", out, "set output_dir to a folder for the report files (null: print only)")
    folder = Path(str(out)).expanduser()
    if folder.is_file():
        raise ConfigError(f"output_dir={out} is a file; give a folder for the report files")
    check_writable("output_dir", folder / "report.md", "give a folder you can write (null: print only)")
    check_bool(cfg, "overwrite")
    overwrite = get(cfg, "overwrite") is True
    page = get(cfg, "teacher.page")
    for name in report_files(get(cfg, "table"), get(cfg, "chart") is not False, None if unset(page) else page):
        path = folder / name
        refusal = replace_refusal("output_dir", path, overwrite, label=f"output_dir={out}: {path}")
        if refusal is not None:
            raise ConfigError(refusal)


def validate_report_config(cfg: DictConfig) -> None:
    """``spade.report``'s checks: the table exists, the MLflow store is there (a missing one would be created
    empty and every row reported missing), and the pages go where they replace nothing unasked
    (:func:`_check_output_dir`)."""
    for key in ("paper", "chart", "log_to_runs", "overwrite"):
        check_bool(cfg, key)  # strict: log_to_runs=maybe would have written into every row's run
    labels = get(cfg, "closed_loop_labels")
    if labels not in (MISSING, None) and not isinstance(labels, dict):
        raise ConfigError(f"closed_loop_labels={labels!r} is not a mapping; set closed_loop_labels={{ROW: LABEL}}")
    table = get(cfg, "table")
    from spade.experiments.tables import get_table

    if str(table) not in ("all", "closed_loop", "teacher", "oracle"):  # not paper tables: their own pages
        try:
            get_table(table)
        except (KeyError, ValueError) as exc:
            raise ConfigError(f"table={table}: {exc.args[0] if exc.args else exc}") from None
    page = get(cfg, "teacher.page")
    if str(table) == "teacher" and not unset(page) and (not isinstance(page, str) or Path(page).name != page
                                                        or page.startswith(".")):
        raise ConfigError(f"teacher.page={page!r} is not a file name; set teacher.page=NAME (the page writes "
                          "NAME.md and NAME.csv into output_dir)")
    uri = get(cfg, "tracking_uri")
    if unset(uri):
        raise ConfigError("tracking_uri is not set; pass tracking_uri=sqlite:///PATH/logs/mlflow.db")
    path = store_path(str(uri))
    # Without a store, a page that has its run records regenerates from them, and a page whose store was lost
    # before it had records keeps its committed copy under a notice (spade.experiments.run_records).
    offline = {"oracle": ("oracle.records_dir",), "teacher": ("teacher.records_dir", "teacher.committed"),
               "closed_loop": ("closed_loop_records_dir", "closed_loop_committed")}.get(str(table), ())
    kept = [get(cfg, key) for key in offline]
    if path is not None and not path.exists() and any(not unset(k) and Path(str(k)).exists() for k in kept):
        check_paths(cfg)  # the page regenerates from its committed run records alone
        _check_output_dir(cfg)
        return
    if path is not None and not path.exists():
        raise ConfigError(f"tracking_uri={uri}: there is no MLflow store at {path} (reporting would create an empty "
                          "one); point tracking_uri (or SPADE_HOME / MLFLOW_TRACKING_URI) at the store the runs were "
                          "logged to")
    if path is not None and str(uri).startswith("sqlite:") and path.is_dir():
        raise ConfigError(f"tracking_uri={uri}: {path} is a directory, not an MLflow SQLite store; point it at the "
                          "store file, e.g. sqlite:///PATH/logs/mlflow.db")
    check_store_file("tracking_uri", str(uri))
    check_server("tracking_uri", str(uri))
    check_paths(cfg)
    _check_output_dir(cfg)
