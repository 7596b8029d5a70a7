"""The teacher and closed-loop pages from run records alone (no store), the lost-store notice of a page without
records, and every committed results page leading with its finding."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "docs" / "results"
PROVENANCE = re.compile(r"^- (command|commit|date|machine|records|wall time|MLflow store|MLflow experiment)\b")


def _record(folder: Path, row: str, seed: int, metrics: dict[str, float], tags: dict[str, str] | None = None,
            end: int = 60_000, status: str = "FINISHED") -> None:
    folder.mkdir(parents=True, exist_ok=True)
    key = f"_{tags['condition_key']}" if tags and "condition_key" in tags else ""
    (folder / f"{row}_s{seed}{key}.json").write_text(json.dumps({
        "row": row, "seed": seed, "run_id": f"{row}{seed}", "start_time": 0, "end_time": end, "metrics": metrics,
        "params": {"cfg/seed": str(seed), "cfg/trainer/max_epochs": "48"}, "instances": [], "tags": tags or {},
        "status": status, "test_sets": ["quickstart/test (abc)"]}))


def _same_but_provenance(a: str, b: str) -> None:
    strip = [line for line in a.splitlines() if not PROVENANCE.match(line)]
    assert strip == [line for line in b.splitlines() if not PROVENANCE.match(line)]


def test_the_teacher_page_regenerates_from_its_records_without_a_store(tmp_path: Path) -> None:
    from spade.experiments.teacher_table import teacher_report

    records = tmp_path / "records"
    _record(records / "teacher", "good", 42, {"test/planner/ape_cm": 2.0, "test/planner/plausibility_cm": 0.8},
            {"encoding": "gaussian"})
    for seed, ape in enumerate((3.9, 4.0, 4.1)):
        _record(records / "encoding", "bc", seed, {"test/planner/ape_cm": ape, "test/planner/plausibility_cm": 2.0,
                                                   "test/baseline/shortest/planner/ape_cm": 40.0},
                {"encoding": "gaussian"})
        _record(records / "teacher", "guided", seed, {"test/planner/ape_cm": ape - 0.05, "margin/active": 0.3},
                {"encoding": "gaussian"})
        _record(records / "closed_loop", "guided__heldout__clean", seed,
                {"closed_loop/success_rate": 1.0, "closed_loop/ape_cm": 12.0 + seed},
                {"source_row": "guided", "dataset": "heldout", "condition": "clean", "condition_key": "k1"})
    _record(records / "_training" / "teacher", "good_training", 42, {}, status="FAILED", end=3_000_000)
    settings = {"page": "teacher", "records_dir": str(records), "committed": str(tmp_path / "none.md"),
                "experts": [{"table": "teacher", "row": "good", "label": "good teacher",
                             "trained_by": {"table": "teacher", "row": "good_training"}}],
                "students": [{"table": "encoding", "row": "bc", "label": "BC gaussian"}],
                "guided": [{"table": "teacher", "row": "guided", "label": "Cond-DBC", "real": False,
                            "against": {"table": "encoding", "row": "bc"}}]}
    store = tmp_path / "lost.db"  # no store: the page is built from the records alone and no store is created
    text, files = teacher_report(f"sqlite:///{store}", tmp_path / "out", settings, "quickstart")
    assert not store.exists() and files["markdown"].read_text() == text
    assert text.startswith("# The teacher") and "| good teacher, one sample | gaussian | 1 | 2.00 |" in text
    assert "| Cond-DBC | held-out map | 3 | 3.95 ± 0.10 |" in text and "| 100% | 13.00 ± 1.00 | 30% |" in text
    assert "status FAILED" in text and "Store lost" not in text
    assert text.split("\n\n")[1].startswith("1 of 1 experts plan better than their student")
    again, _ = teacher_report(f"sqlite:///{store}", None, settings, "quickstart")
    _same_but_provenance(text, again)


def test_the_closed_loop_page_regenerates_from_its_records_without_a_store(tmp_path: Path) -> None:
    from spade.experiments.closed_loop_table import closed_loop_report

    records = tmp_path / "records"
    for seed in range(3):
        for row, ape, success in (("bc", 10.0, 1.0), ("cond", 20.0, 0.9)):
            _record(records, f"{row}__heldout__clean", seed, {
                "closed_loop/ape_cm": ape + seed, "closed_loop/success_rate": success + 0.01 * seed,
                "closed_loop/episodes": 100.0, "closed_loop/baseline/shortest/ape_cm": 40.0 + seed,
                "closed_loop/baseline/shortest/success_rate": 1.0},
                {"source_row": row, "dataset": "heldout", "condition": "clean", "condition_key": "new"},
                end=100_000)
    # a drive under the condition's earlier settings: never shown beside the latest
    _record(records, "bc__heldout__clean", 0, {"closed_loop/ape_cm": 99.0, "closed_loop/success_rate": 0.0},
            {"source_row": "bc", "dataset": "heldout", "condition": "clean", "condition_key": "old"}, end=50_000)
    store = tmp_path / "lost.db"
    text, files = closed_loop_report(f"sqlite:///{store}", tmp_path / "out", None,
                                     labels={"bc": "BC", "cond": "Cond-DBC"}, records_dir=records)
    assert not store.exists() and files["markdown"].read_text() == text
    assert text.startswith("# Closed loop") and "| BC | 3 |" in text and "99.00" not in text
    verdict = text.split("\n\n")[1]
    assert verdict.startswith("Driven in closed loop, 1 of 1 comparisons between students are told apart: BC wins")
    assert "../reference/metrics.md#which-figure-decides" in text
    assert "| heldout, clean: BC vs Cond-DBC | ape_cm |" in text.split("??? note")[0]  # significant: shown
    again, _ = closed_loop_report(f"sqlite:///{store}", None, None, labels={"bc": "BC", "cond": "Cond-DBC"},
                                  records_dir=records)
    _same_but_provenance(text, again)


def test_a_page_without_records_keeps_its_committed_copy_under_the_lost_store_notice(tmp_path: Path) -> None:
    from spade.experiments.closed_loop_table import closed_loop_report
    from spade.experiments.run_records import LOST_STORE
    from spade.experiments.teacher_table import teacher_report

    committed = tmp_path / "committed.md"
    committed.write_text("# A page\n\nIts verdict.\n\n| a |\n|---|\n| 1 |\n")
    uri = f"sqlite:///{tmp_path}/lost.db"
    text, files = closed_loop_report(uri, tmp_path / "out", records_dir=tmp_path / "none", committed=committed)
    lines = text.splitlines()
    assert lines[0] == "# A page" and lines[2].startswith(LOST_STORE) and lines[4] == "Its verdict."
    assert "`python -m spade.closed_loop`" in lines[2] and "figures below are from that store" in lines[2]
    assert files["markdown"].read_text() == text and not (tmp_path / "lost.db").exists()
    committed.write_text(text)  # kept again: still one notice
    again, _ = closed_loop_report(uri, None, records_dir=tmp_path / "none", committed=committed)
    assert again == text
    settings = {"page": "teacher_width", "records_dir": str(tmp_path / "none"), "committed": str(committed),
                "experts": [], "students": []}
    teacher, _ = teacher_report(uri, None, settings)
    assert teacher.count(LOST_STORE) == 1 and "table=teacher teacher=width" in teacher
    # the committed pages whose store was lost say so, once, under their title
    for name in ("teacher.md", "teacher_width.md", "closed_loop.md", "encoding.md", "guidance.md", "sizing.md"):
        page = (RESULTS / name).read_text().splitlines()
        assert page[2].startswith(LOST_STORE) and sum(line.startswith(LOST_STORE) for line in page) == 1, name


def test_a_paper_table_without_runs_keeps_its_committed_page_under_the_notice(tmp_path: Path) -> None:
    """spade.report table=encoding committed=PAGE: no store (or none of the table's runs in it) keeps the committed
    page, naming the commands that rerun it; never creating the store."""
    from spade.experiments.reporting.pages import page
    from spade.experiments.run_records import LOST_STORE
    from spade.utils.config import compose_config

    committed = tmp_path / "encoding.md"
    committed.write_text("# Markers\n\nIts verdict.\n")
    cfg = compose_config("report", ["table=encoding", f"committed={committed}", f"output_dir={tmp_path / 'out'}",
                                    f"tracking_uri=sqlite:///{tmp_path}/lost.db"])
    (report,) = page("encoding").build(cfg)
    lines = (tmp_path / "out" / "encoding.md").read_text().splitlines()
    assert lines[0] == "# Markers" and lines[2].startswith(LOST_STORE) and lines[4] == "Its verdict."
    assert "`python -m spade.train +experiment=encoding`, then `python -m spade.report table=encoding`" in lines[2]
    assert "run records" not in lines[2] and not (tmp_path / "lost.db").exists()


#: Pages written by a bench or a critic command (spade.perf.*, spade.critic) that lead with no verdict yet: the
#: generators of alternatives.md and code_shape.md write none, and the committed critic pages predate the critic's
#: verdict (spade.experiments.critic_run.critic_verdict; their next run writes it). A verdict typed into them by
#: hand would not survive that run (and figures are never typed by hand).
BENCH_PAGES = ("critic_", "alternatives.md", "code_shape.md")


@pytest.mark.parametrize("page", sorted(p.name for p in RESULTS.glob("*.md")
                                        if p.name != "README.md" and not p.name.startswith(BENCH_PAGES)))
def test_every_results_page_leads_with_its_title_and_verdict(page: str) -> None:
    """One ``# `` title, then (past a lost-store notice or a ``## Verdict`` heading) prose, the verdict, before the
    first table; the page links to the metrics reference's statement of which figure decides."""
    lines = (RESULTS / page).read_text().splitlines()
    assert lines[0].startswith("# ") and not lines[0].startswith("##"), f"{page}: no single # title"
    assert sum(line.startswith("# ") for line in lines) == 1, f"{page}: more than one title"
    first_table = next(i for i, line in enumerate(lines) if line.startswith("|"))
    prose = [line for line in lines[1:first_table] if line.strip() and not line.startswith((">", "#"))]
    assert prose and not prose[0].startswith(("|", "!", "???")), f"{page}: no verdict before its first table"
    assert "reference/metrics.md" in "\n".join(lines), f"{page}: no link to the metrics reference"


def test_the_index_and_home_quote_each_pages_finding() -> None:
    import importlib.util

    spec = importlib.util.spec_from_file_location("docs_hook", REPO / "docs" / "hooks" / "spade_docs.py")
    hook = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(hook)
    listing = hook.results_listing(RESULTS, "README.md")
    assert "(teacher.md): No expert plans better than its student" in listing
    assert "(closed_loop.md): Driven in closed loop" in listing
    home = hook.on_page_markdown((REPO / "docs" / "index.md").read_text(),
                                 type("P", (), {"file": type("F", (), {"src_uri": "index.md"})()})(),
                                 {"docs_dir": str(REPO / "docs")}, None)
    assert "spade:findings" not in home and "Against the classical planners the students win" in home
    assert "Guidance from the teacher does not change the planner's APE" in home
