"""A paper table's report from its MLflow runs (what ``python -m spade.report`` prints and writes).

Modules, one job each: ``stats`` (the one statistics kernel of every results page: Welch's, paired and
one-sample tests, Holm's correction, ``mean ± sd``), ``pages`` (the pages ``spade.report`` writes, by name: what
builds each and which files it writes), ``results`` (each row's runs over seeds at one scale,
:func:`fetch_results`, the headline comparisons with Welch's t-test, :func:`compare`, and the pairwise tests,
:func:`pairwise`), ``render`` (the markdown), ``files`` (the CSV files), ``chart`` (the PNG) and ``build``
(:func:`build_report` puts one table's report together; ``pages.report`` those a config asks for). The tables
themselves are :mod:`spade.tracking.tables`; publishing into MLflow is
:func:`spade.tracking.report.publish_report`.
"""

from spade.experiments.reporting.build import Report, build_report
from spade.experiments.reporting.chart import plot_table
from spade.experiments.reporting.files import write_comparisons_csv, write_csv
from spade.experiments.reporting.render import (
    losses_to_baselines,
    render_comparisons,
    render_notes,
    render_pairwise,
    render_paper_table,
    render_table,
)
from spade.experiments.reporting.results import (
    MISSING,
    ComparisonResult,
    RowResult,
    SeedRun,
    compare,
    fetch_results,
    pairwise,
)
from spade.experiments.reporting.stats import ALPHA, holm, mean_sd, welch

__all__ = [
    "ALPHA",
    "MISSING",
    "ComparisonResult",
    "Report",
    "RowResult",
    "SeedRun",
    "build_report",
    "compare",
    "fetch_results",
    "holm",
    "mean_sd",
    "pairwise",
    "losses_to_baselines",
    "plot_table",
    "render_comparisons",
    "render_notes",
    "render_pairwise",
    "render_paper_table",
    "render_table",
    "welch",
    "write_comparisons_csv",
    "write_csv",
]
