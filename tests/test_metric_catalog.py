"""One catalog of metrics: every figure a metric computes is catalogued, and the pages that show figures take their
labels and formats from it instead of spelling them again."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

from spade.metrics import catalog

PACKAGE = Path(__file__).resolve().parents[1] / "spade"

# Modules that render figures (tables, reports, gpu_check, the bench, verdicts): none may spell a label itself.
RENDERERS = [
    "tracking/tables.py",
    "experiments/teacher_table.py",
    "experiments/closed_loop_table.py",
    *sorted(str(p.relative_to(PACKAGE)) for p in (PACKAGE / "experiments" / "reporting").glob("*.py")),
    "perf/gpu.py",
    "perf/bench_report.py",
    "metrics/verdict.py",
    "tracking/descriptions.py",
    "tracking/summary.py",
    "tracking/predictors.py",
    "experiments/run.py",
    "critic.py",
]
# A label's spelling: the tail in any spacing, a unit in brackets, or a column header as a whole string (a word in
# a sentence, "plausibility 0.80 cm", is prose, not a label).
LABEL_SPELLING = re.compile(r">\s*20\s*cm|\((cm|ms|px|deg/m)\)")
BARE_LABELS = {"FID", "Hd19", "APE cm", "APE (cm)"}


def _strings(path: Path) -> list[tuple[int, str]]:
    """Every string constant of a module (f-strings' literal parts included), docstrings left out."""
    tree = ast.parse(path.read_text(), str(path))
    docstrings = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            body = getattr(node, "body", [])
            if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
                docstrings.add(id(body[0].value))
        if isinstance(node, (ast.Module, ast.ClassDef)):  # attribute docstrings: a string after an assignment
            for prev, cur in zip(node.body, node.body[1:]):
                if isinstance(prev, (ast.Assign, ast.AnnAssign)) and isinstance(cur, ast.Expr) \
                        and isinstance(cur.value, ast.Constant):
                    docstrings.add(id(cur.value))
    return [(n.lineno, n.value) for n in ast.walk(tree)
            if isinstance(n, ast.Constant) and isinstance(n.value, str) and id(n) not in docstrings]


@pytest.mark.parametrize("module", RENDERERS)
def test_renderers_spell_no_label_of_their_own(module: str) -> None:
    path = PACKAGE / module
    found = [f"{module}:{line}: {text!r}" for line, text in _strings(path)
             if LABEL_SPELLING.search(text) or text.strip() in BARE_LABELS]
    assert not found, "spell these labels with spade.metrics.catalog (label, fmt):\n" + "\n".join(found)


def test_every_figure_the_metrics_compute_is_catalogued() -> None:
    from spade.metrics.closed_loop import CLOSED_LOOP_KEYS
    from spade.metrics.path_metrics import BASELINE_PLANNER_KEYS, PLANNER_KEYS, PathMetrics
    from spade.metrics.preference import PREFERENCE_KEYS

    names = set(PathMetrics(planner=False, fid=False).compute())
    names |= {f"planner/{k}" for k in (*PLANNER_KEYS, *BASELINE_PLANNER_KEYS, "low_share_mean", "ape_std_cm",
                                      "failures", "instances", "hd19_rate", "hausdorff_mean_px")}
    names |= {"floor_cm", *PREFERENCE_KEYS, "fid", "fid_real_count", "fid_fake_count"}
    names |= {f"closed_loop/{k}" for k in CLOSED_LOOP_KEYS}
    names |= {"planner/spread_cm", "planner/spread_ratio", "generator_spread_cm", "seconds_per_sample",
              "mean_map/planner/ape_cm", "model/params", "margin/active"}
    missing = sorted(n for n in names if not catalog.known(n))
    assert not missing, f"not in spade.metrics.catalog: {missing}"


def test_prefixes_and_stages_resolve_to_one_entry() -> None:
    assert catalog.label("ape_cm") == "APE (cm)"
    assert catalog.label("test/planner/ape_cm") == "planner APE (cm)"
    assert catalog.label("test/baseline/straight/planner/ape_cm") == "planner APE (cm)"
    assert catalog.label("untrained/over_20cm_rate") == catalog.label("over_20cm_rate") == ">20 cm"
    assert catalog.label("closed_loop/baseline/shortest/ape_cm", qualified=False) == "APE (cm)"
    assert catalog.label("closed_loop/success_rate") == "success"
    assert catalog.label("mean_map/planner/hd19") == "mean-map planner Hd19"
    assert catalog.mlflow_key("planner/ape_cm") == "test/planner/ape_cm"
    assert catalog.mlflow_key("model/params") == "model/params"
    assert catalog.fmt("over_20cm_rate", 0.125) == "12.5%"
    assert catalog.fmt("over_20cm_rate", 0.125, compact=True) == "12"
    assert catalog.fmt("planner/ape_cm", 1.234) == "1.23" and catalog.fmt("ape_cm", 1.234, compact=True) == "1.2"
    assert catalog.fmt("model/params", 1_926_209) == "1.93M" and catalog.fmt("fid", float("nan")) == "n/a"
    assert catalog.lower_is_better("planner/commit_rate") is False
    assert catalog.lower_is_better("closed_loop/collision_rate") is True
    assert catalog.lower_is_better("closed_loop/plan_ms") is None
    with pytest.raises(KeyError, match="not in the metric catalog"):
        catalog.figure("test/planner/nonsense_cm")


def test_each_label_and_header_names_one_figure() -> None:
    entries = catalog._ENTRIES
    for attr in ("label", "header"):
        spelled = [getattr(f, attr) for f in entries]
        twice = sorted({s for s in spelled if spelled.count(s) > 1})
        assert not twice, f"{attr}s used by two figures: {twice}"
    for names in (catalog.CELL, catalog.PREFERENCE, catalog.TABLE, catalog.DESCRIPTION, catalog.SUMMARY,
                  catalog.HEADLINE, catalog.TEACHER, catalog.CLOSED_LOOP, catalog.GPU_CHECK):
        assert all(catalog.known(n) for n in names), names


def test_tables_and_pages_draw_labels_and_formats_from_the_catalog() -> None:
    from spade.experiments import closed_loop_table, teacher_table
    from spade.tracking.tables import CELL_METRICS, METRICS, PREFERENCE_METRICS

    for key, metric in METRICS.items():
        assert metric == catalog.figure(metric.name) and metric.key == key
    assert [METRICS[k].name for k in CELL_METRICS] == list(catalog.CELL)
    assert [METRICS[k].name for k in PREFERENCE_METRICS] == list(catalog.PREFERENCE)
    for label, key, fmt in teacher_table.COLUMNS:
        assert (label, fmt) == (catalog.label(key), catalog.figure(key).fmt)
    for label, key, fmt, lower in closed_loop_table.FIGURES:
        name = f"closed_loop/{key}"
        assert (label, fmt, lower) == (catalog.label(name, qualified=False), catalog.figure(name).fmt,
                                       catalog.lower_is_better(name))


def test_gpu_check_report_heads_its_figures_with_catalog_labels() -> None:
    from spade.perf.gpu import format_gpu_report

    results = {"device": {"device": "cpu", "torch": "2"}, "precision": "fp32", "seconds": 1.0,
               "pipeline": {"timed_out": False, "exit_code": 0, "wall_s": 3.0, "command": "python -m spade.train",
                            "runs": [{"run": "r", "status": "FINISHED", "wall_s": 2.0, "ape_cm": 1.5}]}}
    text = format_gpu_report(results)
    header = next(line for line in text.splitlines() if line.startswith("| run |"))
    assert header.split(" | ")[3:] == [*map(catalog.label, catalog.GPU_CHECK[:-1]),
                                       catalog.label(catalog.GPU_CHECK[-1]) + " |"]
    assert "| r | FINISHED | 2.0 | 1.5 | - |" in text
