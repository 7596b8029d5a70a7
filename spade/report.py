"""``python -m spade.report [table=table1|table2|table3|all] [scale=...]``: a paper table from the MLflow runs.

Reads the finished runs of a table's MLflow experiment (run name = row name; see
:mod:`spade.tracking.tables`) at one scale, one run per distinct seed (the latest run of a seed counts),
prints the table in the paper's layout as markdown, each cell the mean +/- sd over the seeds, with the
paper's headline comparisons and pairwise tests (Welch's t-test over the per-seed values), and writes
``<table>.md``, ``<table>.csv``, ``<table>_comparisons.csv`` and a ``<table>.png`` chart into
``output_dir``. A row without a finished run is shown as missing, never dropped. The work is done by
:mod:`spade.experiments.reporting` (:func:`~spade.experiments.reporting.pages.report`); this is its entry point.
"""

from __future__ import annotations

import hydra
from omegaconf import DictConfig

from spade.paths import CONFIG_PATH  # the configs (conf/ or the installed copy); registers the resolvers
from spade.utils.errors import run_entry_point, task
from spade.experiments.reporting.pages import report


@hydra.main(version_base="1.3", config_path=CONFIG_PATH, config_name="report")
@task
def main(cfg: DictConfig) -> None:
    from spade.config.refusals import exit_on_user_error

    for rep in exit_on_user_error(report)(cfg):  # a missing store or table: one `error:` line, exit 2
        print(rep.text + "\n", flush=True)


if __name__ == "__main__":
    run_entry_point(main)
