"""``spade.report``'s checks: the table exists, the MLflow store is there, and the pages it writes replace only
earlier pages of SPADE's, with ``overwrite=true``. The pages themselves are handed in (their registry,
:mod:`spade.experiments.reporting.pages`): the checks import no page."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, Protocol

from omegaconf import DictConfig

from spade.deploy.outputs import replace_refusal
from spade.config.file_checks import check_path_value, check_paths, check_writable
from spade.config.store_checks import store_path, check_server, check_store_file
from spade.config.options import read_options, resolve
from spade.utils.errors import ConfigError
from spade.utils.option_checks import MISSING, check_bool_value, unset


class ReportPage(Protocol):
    """What the checks need of a page of ``spade.report`` (:class:`spade.experiments.reporting.pages.Page`): the
    files it writes into ``output_dir`` and the settings that let it regenerate without the store."""

    offline: tuple[str, ...]

    def files(self, chart: bool, page: str | None) -> list[str]: ...


Pages = Callable[[Any], ReportPage]
"""The page ``table=NAME`` asks for (:func:`spade.experiments.reporting.pages.page`): a ValueError names the
tables for an unknown one."""


@dataclass(frozen=True)
class ReportOptions:
    """``spade.report``'s options (conf/report.yaml) that its checks read; each table's own settings (``teacher.*``,
    ``oracle.*``) are its page's."""

    node: ClassVar[str] = ""
    table: Any = None
    tracking_uri: Any = None
    output_dir: Any = None
    overwrite: bool | None = False
    chart: bool | None = True
    paper: bool | None = None
    log_to_runs: bool | None = None
    closed_loop_labels: Any = None

    def __post_init__(self) -> None:
        for key in ("paper", "chart", "log_to_runs", "overwrite"):
            check_bool_value(key, getattr(self, key))  # strict: log_to_runs=maybe would have written into every run
        labels = self.closed_loop_labels
        if labels is not None and not isinstance(labels, dict):
            raise ConfigError(f"closed_loop_labels={labels!r} is not a mapping; set closed_loop_labels={{ROW: LABEL}}")


def _check_output_dir(options: ReportOptions, page: ReportPage, stem: Any) -> None:
    """``output_dir`` (null: print only) is a folder path, neither empty nor the root, and none of the pages the
    report would write there exists unless SPADE wrote it and ``overwrite=true``: refused before any run is read."""
    out = options.output_dir
    if out is None:
        return
    check_path_value("output_dir", out, "set output_dir to a folder for the report files (null: print only)")
    folder = Path(str(out)).expanduser()
    if folder.is_file():
        raise ConfigError(f"output_dir={out} is a file; give a folder for the report files")
    check_writable("output_dir", folder / "report.md", "give a folder you can write (null: print only)")
    for name in page.files(options.chart is not False, None if unset(stem) else stem):
        path = folder / name
        refusal = replace_refusal("output_dir", path, options.overwrite is True, label=f"output_dir={out}: {path}")
        if refusal is not None:
            raise ConfigError(refusal)


def validate_report_config(cfg: DictConfig, pages: Pages) -> ReportOptions:
    """``spade.report``'s checks: the table exists (``pages``: the page of a table name), the MLflow store is there
    (a missing one would be created empty and every row reported missing), and the pages go where they replace
    nothing unasked (:func:`_check_output_dir`); returns the command's options."""
    options = read_options(cfg, ReportOptions)
    table = options.table
    try:
        report_page = pages(table)
    except (KeyError, ValueError) as exc:
        raise ConfigError(f"table={table}: {exc.args[0] if exc.args else exc}") from None
    page = resolve(cfg, "teacher.page")  # the teacher page's own setting: the file name it writes
    page = None if page is MISSING else page
    if str(table) == "teacher" and not unset(page) and (not isinstance(page, str) or Path(page).name != page
                                                        or page.startswith(".")):
        raise ConfigError(f"teacher.page={page!r} is not a file name; set teacher.page=NAME (the page writes "
                          "NAME.md and NAME.csv into output_dir)")
    uri = options.tracking_uri
    if unset(uri):
        raise ConfigError("tracking_uri is not set; pass tracking_uri=sqlite:///PATH/logs/mlflow.db")
    path = store_path(str(uri))
    # Without a store, a page that has its run records regenerates from them, and a page whose store was lost
    # before it had records keeps its committed copy under a notice (spade.experiments.run_records).
    kept = [resolve(cfg, key) for key in report_page.offline]
    if path is not None and not path.exists() and any(k is not MISSING and not unset(k) and Path(str(k)).exists()
                                                       for k in kept):
        check_paths(cfg)  # the page regenerates from its committed run records alone
        _check_output_dir(options, report_page, page)
        return options
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
    _check_output_dir(options, report_page, page)
    return options
