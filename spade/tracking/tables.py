"""The paper's tables: which runs fill which cells, the paper's figures, its headlines.

A table is laid out as in the paper: one line per (size, approach) or approach, one cell per shape holding
``FID / APE (cm) / Hd19``. Every cell is one experiment of ``conf/experiment/`` whose run (run name = row
name) lands in the MLflow experiment named after the table (``tags.table`` of the row). ``spade.report``
renders these layouts from MLflow; this module holds only the knowledge of the tables themselves.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from spade.metrics import catalog
from spade.metrics.catalog import BASELINE_ROW_LABELS as BASELINE_LABELS, Figure as Metric, format_params
from spade.models.paper_sizes import PAPER_COND_EXPERT_PARAMETERS, PAPER_PARAMETER_COUNTS as PAPER_PARAMS

__all__ = [
    "BASELINE_LABELS",
    "CELL_METRICS",
    "METRICS",
    "PREFERENCE_METRICS",
    "TABLES",
    "TINY_NOTICE",
    "Comparison",
    "Line",
    "Metric",
    "Table",
    "format_params",
    "get_table",
    "relative_change",
]

METRICS: dict[str, Metric] = {m.key: m for m in map(catalog.figure, catalog.TABLE)}
"""The figures a table reads from its runs (:data:`spade.metrics.catalog.TABLE`), by report key
(``planner_ape_cm``: the CSV column; ``mlflow_key`` is what the run logged, ``test/planner/ape_cm``)."""
CELL_METRICS = tuple(catalog.figure(n).key for n in catalog.CELL)
"""A cell's figures (:data:`spade.metrics.catalog.CELL`), by report key."""
PREFERENCE_METRICS = tuple(catalog.figure(n).key for n in catalog.PREFERENCE)
"""The preference figures beside a table's cells (:data:`spade.metrics.catalog.PREFERENCE`), by report key."""


TINY_NOTICE = ("scale=tiny: a pipeline check, not a result: its figures mean nothing about the methods (scale=cpu "
               "or scale=paper)")
"""What every summary printed at ``scale=tiny`` says (the run summary, ``spade.report``, a table's start message):
one console line (within 120 characters, indented), so that it is found whole wherever it is printed."""


def baseline_metric(name: str, key: str) -> str:
    """The MLflow key of a baseline's metric, e.g. ``test/baseline/straight/ape_cm``."""
    return catalog.mlflow_key(f"baseline/{name}/{METRICS[key].name}")


@dataclass(frozen=True)
class Line:
    """One line of a table: its labels (e.g. ``("medium", "Cond-DBC")``) and the row (experiment) per shape."""

    labels: tuple[str, ...]
    cells: dict[str, str]
    paper: dict[str, dict[str, float]] = field(default_factory=dict)  # shape -> {metric key: paper figure}


@dataclass(frozen=True)
class Comparison:
    """``row`` against ``baseline``: relative change (%) of each metric, with the paper's figure where known.

    ``paper`` holds the paper's relative changes in percent (negative = lower); ``paper_source`` says whether
    they are the paper's stated headline or computed here from the paper's table.
    """

    title: str
    row: str
    baseline: str
    metrics: tuple[str, ...]
    paper: dict[str, float]
    paper_source: str


@dataclass(frozen=True)
class Table:
    """A table of the paper as MLflow holds it: one MLflow experiment, launched by one composition."""

    key: str
    title: str
    experiment: str  # MLflow experiment name (= tags.table of its rows)
    composition: str  # python -m spade.train +experiment=<composition>
    label_columns: tuple[str, ...]
    shapes: tuple[str, ...]
    lines: tuple[Line, ...]
    comparisons: tuple[Comparison, ...] = ()
    # Columns whose cells are not experiments but another test of a row's checkpoint (``also_test``: run
    # ``<row>_<column>``, :func:`spade.experiments.run.test_elsewhere`).
    tested_elsewhere: tuple[str, ...] = ()

    @property
    def rows(self) -> list[str]:
        """Every row (run name) of the table, in layout order."""
        return [line.cells[s] for line in self.lines for s in self.shapes if s in line.cells]

    def column_label(self, shape: str) -> str:
        """How a column is headed: ``L-shape`` for a shape, the column's name for a test elsewhere."""
        return f"{shape} maps (another test)" if shape in self.tested_elsewhere else f"{shape}-shape"

    @property
    def experiments(self) -> list[str]:
        """The rows that are experiments (``conf/experiment/<row>.yaml``): all but the ``tested_elsewhere`` cells."""
        return [line.cells[s] for line in self.lines for s in self.shapes
                if s in line.cells and s not in self.tested_elsewhere]

    @property
    def sweep_order(self) -> list[str]:
        """The experiments in the order a table's multirun runs them: per shape, its experts first (the students
        after them need them), then the other rows in layout order. The table's one list of rows: its
        composition (``conf/experiment/<composition>.yaml``) sweeps ``${spade_table_rows:${rows},<key>}``."""
        order: list[str] = []
        for shape in self.shapes:
            if shape in self.tested_elsewhere:
                continue
            column = [line.cells[shape] for line in self.lines if shape in line.cells]
            experts = [r for r in column if r.startswith(EXPERT_ROW_PREFIXES)]
            order += experts + [r for r in column if r not in experts]
        return order

    def describe(self) -> str:
        """A description for the MLflow experiment (shown on its page in the UI)."""
        return (
            f"{self.title}\n\nRows (run names): {', '.join(self.rows)}.\n"
            f"Launch: `python -m spade.train +experiment={self.composition}`; "
            f"report: `python -m spade.report table={self.key}`."
        )


def relative_change(value: float | None, baseline: float | None) -> float | None:
    """``100 * (value - baseline) / baseline`` (negative = lower); None when either is missing or baseline is 0."""
    if value is None or baseline is None or math.isnan(value) or math.isnan(baseline) or baseline == 0:
        return None
    return 100.0 * (value - baseline) / baseline


#: The standalone experts' rows (``cond_expert_L``, ``uncond_expert_U``, ...): in a table's sweep they go first.
EXPERT_ROW_PREFIXES = ("cond_expert_", "uncond_expert_")


def _paper(fid: float, ape: float, hd19: float) -> dict[str, float]:
    return {"fid": fid, "ape_cm": ape, "hd19": hd19}


_T1 = {  # (size, approach) -> {shape: (FID, APE cm, Hd19)}, the paper's Table 1
    ("small", "BC"): {"L": (42.27, 4.43, 28), "U": (35.51, 6.79, 52)},
    ("small", "DBC"): {"L": (24.69, 2.92, 62), "U": (29.86, 6.55, 124)},
    ("small", "Cond-DBC"): {"L": (23.87, 3.14, 43), "U": (27.65, 6.72, 52)},
    ("medium", "BC"): {"L": (31.25, 3.48, 6), "U": (27.80, 6.01, 11)},
    ("medium", "DBC"): {"L": (16.51, 2.21, 1), "U": (15.01, 4.51, 7)},
    ("medium", "Cond-DBC"): {"L": (13.58, 1.46, 2), "U": (13.97, 4.01, 9)},
    ("large", "BC"): {"L": (20.45, 2.41, 5), "U": (17.12, 5.20, 7)},
    ("large", "DBC"): {"L": (15.72, 1.89, 0), "U": (9.59, 2.87, 10)},
    ("large", "Cond-DBC"): {"L": (12.47, 1.47, 5), "U": (12.37, 3.73, 0)},
}
_APPROACH_SLUG = {"BC": "bc", "DBC": "dbc", "Cond-DBC": "conddbc"}


def _table1() -> Table:
    lines = []
    for (size, approach), figures in _T1.items():
        cells = {s: f"t1_{size}_{_APPROACH_SLUG[approach]}_{s}" for s in ("L", "U")}
        paper = {s: {**_paper(*figures[s]), "params": PAPER_PARAMS[size]} for s in figures}
        lines.append(Line((size, approach), cells, paper))
    # The standalone experts (the paper reports some of their figures in the text).
    lines.append(Line(("expert", "Cond-expert"), {s: f"cond_expert_{s}" for s in ("L", "U")},
                      {"L": {"ape_cm": 1.42, "params": PAPER_COND_EXPERT_PARAMETERS}, "U": {"ape_cm": 2.74, "params": PAPER_COND_EXPERT_PARAMETERS}}))
    lines.append(Line(("expert", "Uncond-expert"), {s: f"uncond_expert_{s}" for s in ("L", "U")},
                      {"L": {"fid": 4.84}, "U": {"fid": 2.43}}))
    headline = {"ape_cm": -39.1, "fid": -33.5, "hd19": -60.0, "params": -93.8}
    comparisons = []
    for shape in ("L", "U"):
        med, large = _T1[("medium", "Cond-DBC")][shape], _T1[("large", "BC")][shape]
        derived = {k: relative_change(a, b) for k, a, b in zip(("fid", "ape_cm", "hd19"), med, large)}
        derived["params"] = relative_change(PAPER_PARAMS["medium"], PAPER_PARAMS["large"])
        comparisons.append(Comparison(
            title=f"medium Cond-DBC vs large BC ({shape})",
            row=f"t1_medium_conddbc_{shape}", baseline=f"t1_large_bc_{shape}",
            metrics=("ape_cm", "fid", "hd19", "params"),
            # The paper's headline matches its L-shape rows (computed: -39.4 / -33.6 / -60.0 / -93.8 %).
            paper=headline if shape == "L" else {k: round(v, 1) for k, v in derived.items() if v is not None},
            paper_source="paper's headline" if shape == "L" else "computed from the paper's table",
        ))
    return Table("table1", "Table 1: students (size x approach) and standalone experts, test set per shape",
                 "table1", "table1", ("size", "approach"), ("L", "U"), tuple(lines), tuple(comparisons))


def _ablation(key: str, title: str, composition: str, rows: list[tuple[str, str, tuple]],
              row: str, baseline: str, comparison_title: str) -> Table:
    # Every ablation row is a medium student.
    lines = tuple(Line((label,), {"U": name}, {"U": {**_paper(*figures), "params": PAPER_PARAMS["medium"]}})
                  for label, name, figures in rows)
    figures_by_row = {name: figures for _, name, figures in rows}
    a, b = figures_by_row[row], figures_by_row[baseline]
    derived = {k: round(relative_change(x, y), 1) for k, x, y in zip(("fid", "ape_cm", "hd19"), a, b)}
    comparison = Comparison(comparison_title, row, baseline, ("ape_cm", "fid", "hd19"), derived,
                            "computed from the paper's table")
    return Table(key, title, key, composition, ("approach",), ("U",), lines, (comparison,))


def _table2() -> Table:
    return _ablation(
        "table2", "Table 2: transfer L -> U, fine-tuning models pretrained on L (test on U, new map)",
        "ablation_finetune",
        [("SKIPP BC, fine-tuned (BC)", "t2_bc_finetune_U", (37.43, 7.75, 50)),
         ("Aug. BC, fine-tuned (BC)", "t2_augbc_finetune_bc_U", (25.10, 6.19, 26)),
         ("Aug. BC, fine-tuned (Cond-DBC, L expert)", "t2_augbc_finetune_conddbc_U", (23.55, 5.96, 19))],
        "t2_augbc_finetune_conddbc_U", "t2_bc_finetune_U", "Aug. BC fine-tuned with Cond-DBC vs SKIPP BC fine-tuned",
    )


def _table3() -> Table:
    return _ablation(
        "table3", "Table 3: training from scratch on U (new map)", "ablation_scratch",
        [("SKIPP BC", "t3_bc_scratch_U", (46.08, 8.15, 19)),
         ("Aug. BC (pre-trained L expert)", "t3_augbc_pretrained_expert_U", (44.14, 8.26, 7))],
        "t3_augbc_pretrained_expert_U", "t3_bc_scratch_U", "Aug. BC (pre-trained expert) vs SKIPP BC",
    )


def _guidance() -> Table:
    """Not a table of the paper: BC against the paper's Cond-DBC margin and SPADE's straight-through one
    (``margin=cond_dbc_st``), with few demonstrations and with the scale's, on the held-out map (column L) and on
    real maps no training set uses (column real: run ``<row>_real``, :func:`spade.experiments.run.test_elsewhere`)."""
    lines = []
    for regime in ("few", "full"):
        for approach, slug in (("BC", "bc"), ("Cond-DBC", "conddbc"), ("Cond-DBC-ST", "conddbcst")):
            row = f"g_{regime}_{slug}_L"
            lines.append(Line((regime, approach), {"L": row, "real": f"{row}_real"}))
    return Table("guidance", "Guidance: BC, the paper's margin (Cond-DBC) and the straight-through margin "
                 "(Cond-DBC-ST), few (250) and all (2,000) training instances; tested on the held-out map (L) and "
                 "on unseen real maps (real)", "guidance", "guidance", ("regime", "approach"), ("L", "real"),
                 tuple(lines), tested_elsewhere=("real",))


#: The sizing table's grid: training instances (the first N of one dataset) x epochs.
SIZING_INSTANCES = (300, 1000, 3000)
SIZING_EPOCHS = (3, 10)


def _sizing() -> Table:
    """Not a table of the paper: how many demonstrations and epochs a user's own-map student needs. The own-map
    tutorial's small BC student on one real map (``data=onemap_L``), trained on one side of it and tested on the
    other, for each instances x epochs of the grid; the pairwise tests compare the epochs at one size."""
    lines = tuple(Line((f"{n:,} instances", f"{e} epochs"), {"L": f"sz_n{n}_e{e}_L"})
                  for n in SIZING_INSTANCES for e in SIZING_EPOCHS)
    return Table("sizing", "Sizing on your own map: a small BC student trained on N instances of one real map (the "
                 "Carter warehouse) for E epochs, tested on the part of the map it never saw", "sizing", "sizing",
                 ("instances", "epochs"), ("L",), lines)


def _encoding() -> Table:
    """Not a table of the paper: which start and goal markers a student's input should draw: the paper's
    binary discs, an anti-aliased disc and a Gaussian blob at the exact position (``data.encoding``), medium BC
    students on the held-out map (L) and unseen real maps (real, run ``<row>_real``)."""
    lines = tuple(Line((label,), {"L": f"enc_{name}_L", "real": f"enc_{name}_L_real"})
                  for label, name in (("binary discs (paper)", "binary"), ("anti-aliased disc", "aa_disc"),
                                      ("Gaussian blob", "gaussian")))
    return Table("encoding", "Start and goal markers: the paper's binary discs against sub-pixel encodings (medium "
                 "BC students; held-out map L, unseen real maps real)", "encoding", "encoding", ("encoding",),
                 ("L", "real"), lines, tested_elsewhere=("real",))


TABLES: dict[str, Table] = {t.key: t for t in (_table1(), _table2(), _table3(), _guidance(), _sizing(),
                                               _encoding())}
_ALIASES = {"1": "table1", "2": "table2", "3": "table3"} | {t.composition: t.key for t in TABLES.values()}


def get_table(name: str) -> Table:
    """A table by key (``table1``), number (``1``) or composition name (``ablation_finetune``)."""
    key = _ALIASES.get(str(name), str(name))
    if key not in TABLES:
        choices = ", ".join([*TABLES, *(k for k in _ALIASES if k not in TABLES)])
        raise ValueError(f"unknown table {name!r}; choose one of: {choices}")
    return TABLES[key]
