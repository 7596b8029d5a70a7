"""The pages ``spade.report`` writes, by name (``table=NAME``): what builds each, the files it writes into
``output_dir`` and the settings whose run records let it regenerate without the MLflow store.

Every page registers here, so that the report's config checks (:mod:`spade.config.report_checks`) learn a page's
files from its :class:`Page` (handed to them by :func:`report`) and never import a page module; a new page is one :func:`register` call and its module. The paper's tables
(:mod:`spade.tracking.tables`) are pages too, each by its key, number or composition (:func:`page`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from omegaconf import DictConfig, OmegaConf

from spade.config.report_checks import validate_report_config
from spade.experiments.closed_loop_table import closed_loop_report
from spade.experiments.oracle_page import oracle_report
from spade.experiments.precision_page import precision_report
from spade.experiments.reporting.build import Report, build_report
from spade.experiments.run_records import experiment_has_runs, keep_committed_page
from spade.tracking.tables import TABLES, Table, get_table
from spade.experiments.teacher_table import TEACHER_TABLE, teacher_files, teacher_report

__all__ = ["PAGES", "Page", "page", "register", "report", "report_files"]

@dataclass(frozen=True)
class Page:
    """A page of ``spade.report``: ``files(chart, page)`` names what it writes into ``output_dir`` (``chart``: the
    report's ``chart`` option; ``page``: the page's own file stem, ``teacher.page``); ``build(cfg)`` renders it,
    returning its reports; ``offline`` are the config keys whose records (or committed page) let it regenerate
    without the store."""

    name: str
    files: Callable[[bool, str | None], list[str]]
    build: Callable[[DictConfig], list[Any]]
    offline: tuple[str, ...] = field(default=())


PAGES: dict[str, Page] = {}
"""Every page but the paper tables, by name."""


def register(new: Page) -> Page:
    PAGES[new.name] = new
    return new


def page(name: Any) -> Page:
    """The page ``table=name`` asks for: a registered page, ``all`` (every paper table) or one paper table (by key,
    number or composition); a :class:`ValueError` naming the tables for any other name."""
    if str(name) in PAGES:
        return PAGES[str(name)]
    if str(name) == "all":
        return Page("all", lambda chart, _: [f for t in TABLES.values() for f in _table_files(t, chart)],
                    lambda cfg: [_build_table(t, cfg) for t in TABLES.values()])
    table = get_table(name)
    return Page(table.key, lambda chart, _: _table_files(table, chart), lambda cfg: [_build_table(table, cfg)],
                ("committed",))


def report_files(table: Any, chart: bool = True, teacher_page: Any = None) -> list[str]:
    """The names of the files ``spade.report`` writes into ``output_dir`` for ``table`` (a table without
    comparisons writes no ``_comparisons.csv``: listed anyway, an existing one is not replaced unasked either)."""
    return page(table).files(chart, teacher_page)


def _table_files(table: Table, chart: bool) -> list[str]:
    key = table.key
    return [f"{key}.md", f"{key}.csv", f"{key}_comparisons.csv", *([f"{key}.png"] if chart else [])]


def _scale(cfg: DictConfig) -> str | None:
    return cfg.scale.name if cfg.get("scale") else None


def _build_table(table: Table, cfg: DictConfig) -> Any:
    """One paper table's report; without any of its runs in the store, its ``committed`` page (when given) is kept
    under the lost-store notice, naming the commands that rerun it."""
    committed = cfg.get("committed")
    if committed and not experiment_has_runs(cfg.tracking_uri, table.experiment):
        command = (f"`python -m spade.train +experiment={table.composition}`, then "
                   f"`python -m spade.report table={table.key}`")
        kept = keep_committed_page(committed, command, None, cfg.get("output_dir"), f"{table.key}.md")
        if kept is not None:
            return _page_report(*kept)
    # `scale` is the config group of conf/scale (so that scale=cpu reads as everywhere else); its name filters runs.
    return build_report(table, cfg.tracking_uri, cfg.get("output_dir"), _scale(cfg), cfg.get("paper", True),
                        cfg.get("chart", True), cfg.get("log_to_runs", False) is True)


def _page_report(text: str, files: dict) -> Any:
    return Report(None, {}, [], text, files)  # type: ignore[arg-type]


def _closed_loop(cfg: DictConfig) -> list[Any]:
    """The drives of trained rows (:mod:`spade.experiments.closed_loop_table`)."""
    return [_page_report(*closed_loop_report(cfg.tracking_uri, cfg.get("output_dir"), _scale(cfg),
                                             labels=cfg.get("closed_loop_labels"),
                                             records_dir=cfg.get("closed_loop_records_dir"),
                                             committed=cfg.get("closed_loop_committed")))]


def _teacher(cfg: DictConfig) -> list[Any]:
    """The experts as planners (:mod:`spade.experiments.teacher_table`)."""
    settings = OmegaConf.to_container(cfg.teacher, resolve=True) if cfg.get("teacher") else {}
    return [_page_report(*teacher_report(cfg.tracking_uri, cfg.get("output_dir"), settings, _scale(cfg)))]


def _oracle(cfg: DictConfig) -> list[Any]:
    """Where a teacher teaches (:mod:`spade.experiments.oracle_page`)."""
    settings = OmegaConf.to_container(cfg.oracle, resolve=True)
    return [_page_report(*oracle_report(cfg.tracking_uri, cfg.get("output_dir"), settings))]


register(Page("closed_loop", lambda chart, _: ["closed_loop.md", "closed_loop.csv"], _closed_loop,
              ("closed_loop_records_dir", "closed_loop_committed")))
register(Page(TEACHER_TABLE, lambda chart, stem: list(teacher_files(stem)), _teacher,
              ("teacher.records_dir", "teacher.committed")))
register(Page("oracle", lambda chart, _: ["oracle.md", "oracle_curve.png"], _oracle, ("oracle.records_dir",)))


def _precision(cfg: DictConfig) -> list[Any]:
    """The bf16 science check (:mod:`spade.experiments.precision_page`)."""
    settings = OmegaConf.to_container(cfg.precision, resolve=True)
    return [_page_report(*precision_report(cfg.tracking_uri, cfg.get("output_dir"), settings))]


register(Page("precision", lambda chart, _: ["precision.md"], _precision, ("precision.records_dir",)))


def report(cfg: DictConfig) -> list[Report]:
    """The reports of ``cfg.table`` (one table, every table with ``table=all``, or a registered page); a store that
    does not exist is refused (:class:`~spade.utils.errors.ConfigError`), never created empty and reported all
    missing."""
    validate_report_config(cfg, page)
    return page(cfg.table).build(cfg)
