"""The hostile probes' classifier (clear, unclear, wrong on canned outputs), the page section rendered from a
record, and three probes end to end (slow; the whole run is a benchmark: python -m spade.perf.hostile_probes)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from spade.perf.hostile_probes import BEGIN, END, PROBES, Outcome, classify, probe_all, render_section, update_page

CLEAR = "[12:00:00][INFO] loading\nerror: ckpt_path=/x/a_folder is a directory; pass a .ckpt file\n"


@pytest.mark.parametrize("outcome, names, verdict, why", [
    (Outcome(2, CLEAR), "a_folder", "clear", ""),
    (Outcome(2, CLEAR), "ckpt_path", "clear", ""),
    (Outcome(2, CLEAR), "data.test_dir", "unclear", "does not name 'data.test_dir'"),
    (Outcome(1, "Traceback (most recent call last):\n  File ...\nValueError: bad\n" + CLEAR), "", "unclear",
     "a traceback"),
    (Outcome(2, "error: ckpt_path is a directory\n"), "", "unclear", "without its fix"),
    (Outcome(2, CLEAR + "error: and another; fix\n"), "", "unclear", "2 error: lines"),
    (Outcome(1, "something failed\n"), "", "unclear", "0 error: lines"),
    (Outcome(0, "closed loop: 0 drives run\n"), "", "unclear", "exit 0 on bad input"),
    (Outcome(None, ""), "", "unclear", "still running"),
    (Outcome(2, CLEAR, left="a FAILED run"), "", "unclear", "left a FAILED run"),
    (Outcome(0, "plan written to plan.png\n", acted=True), "", "wrong", "accepted and acted on"),
    (Outcome(2, CLEAR, acted=True), "", "wrong", "accepted and acted on"),  # made its output, then refused
    (Outcome(0, "", ok=True), "", "clear", ""),  # a race that every process came through
])
def test_the_classifier_reads_canned_outcomes(outcome: Outcome, names: str, verdict: str, why: str) -> None:
    got, reason = classify(outcome, names)
    assert got == verdict and why in reason, (got, reason)


def test_a_verifier_report_is_clear_when_it_names_the_file_and_the_fix() -> None:
    report = ("/d: 1 problem(s)\n  - /d/pose.bin: instance 0 holds NaN or inf (4 instance(s) in all): the file's "
              "values are not a dataset's. Re-generate the dataset (python -m spade.annotate ...).\n")
    assert classify(Outcome(1, report), "pose", report=True) == ("clear", "")
    assert classify(Outcome(0, "/d: OK, 4 instances\n"), "pose", report=True)[0] == "unclear"
    assert classify(Outcome(1, report), "pose")[0] == "unclear"  # not a verifier: one error: line is asked for


def test_the_probes_have_distinct_names_and_bounded_time() -> None:
    names = [p.name for p in PROBES]
    assert len(names) == len(set(names)) and len(names) >= 50
    assert all(0 < p.timeout <= 600 for p in PROBES)


def record(counts: dict[str, int], rows: list[dict]) -> dict:
    return {"command": "python -m spade.perf.hostile_probes out.json", "commit": "abc123", "date": "2026-01-01 00:00 UTC",
            "machine": "host: cpu, 2 cores", "wall_s": 60, "counts": counts, "probes": rows}


def test_the_section_is_rendered_from_the_record(tmp_path: Path) -> None:
    rows = [{"name": "a", "cause": "inputs", "verdict": "clear", "why": ""},
            {"name": "b", "cause": "huge maps", "verdict": "unclear", "why": "a traceback"},
            {"name": "c", "cause": "a forged | model", "verdict": "wrong", "why": "accepted"},
            {"name": "d", "cause": "Foxglove", "verdict": "skipped", "why": "needs foxglove, not installed"}]
    text = render_section(record({"clear": 1, "unclear": 1, "wrong": 1, "skipped": 1}, rows))
    assert text.startswith(BEGIN) and text.endswith(END)
    assert "3 probes run: **1 clear, 1 unclear, 1 wrong**; 1 skipped." in text and "commit: abc123" in text
    assert "| `b` | huge maps | unclear | a traceback |" in text and "a forged \\| model" in text
    assert "`a`" not in text  # clear rows are counted, not listed
    page = tmp_path / "page.md"
    page.write_text(f"# Page\n\n{BEGIN}\nold\n{END}\n\nafter\n")
    update_page(record({"clear": 1, "unclear": 0, "wrong": 0, "skipped": 0}, rows[:1]), page)
    assert page.read_text().startswith("# Page\n\n" + BEGIN) and page.read_text().endswith(END + "\n\nafter\n")
    assert "old" not in page.read_text()
    page.write_text("no markers")
    with pytest.raises(ValueError, match="marker"):
        update_page(record({"clear": 0, "unclear": 0, "wrong": 0, "skipped": 0}, []), page)


@pytest.mark.slow
def test_three_probes_end_to_end(tmp_path: Path) -> None:
    out = tmp_path / "probes.json"
    probe_all(out, ["verify-nan-poses", "evaluate-folder-ckpt", "closed-loop-mistyped-store"])
    rows = {r["name"]: r for r in json.loads(out.read_text())["probes"]}
    assert set(rows) == {"verify-nan-poses", "evaluate-folder-ckpt", "closed-loop-mistyped-store"}
    assert {name: r["verdict"] for name, r in rows.items()} == dict.fromkeys(rows, "clear"), rows
