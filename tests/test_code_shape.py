"""spade.perf.code_shape counts what the periphery issue reports, in a checkout: a tiny hand-made package."""

from __future__ import annotations

from pathlib import Path


def _write(root: Path, rel: str, text: str) -> None:
    path = root / rel
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)


def test_code_shape_counts_modules_lines_clients_and_spellings(tmp_path: Path) -> None:
    from spade.perf.code_shape import measure, render

    _write(tmp_path, "spade/__init__.py", "")
    _write(tmp_path, "spade/train.py", "import sys\nimport spade.experiments.tracking.record\n"
                                       "if __name__ == '__main__' and '--help' in sys.argv:\n    print('help')\n")
    _write(tmp_path, "spade/experiments/__init__.py", "")
    _write(tmp_path, "spade/experiments/tracking/__init__.py", "")
    _write(tmp_path, "spade/experiments/tracking/record.py",
           "def client():\n\n    return MlflowClient(uri)  # built here\n\nKEY = 'test/ape_cm'\nTAIL = '> 20 cm'\n")
    _write(tmp_path, "spade/experiments/run.py", "x = 1\n")  # not imported by spade.train
    _write(tmp_path, "spade/config/train_checks.py", "A = \"ape_cm\"\nB = 'over_20cm_rate'\n")
    _write(tmp_path, "spade/tables.py", "'''A docstring naming ``MlflowClient(`` in backticks is not a construction.'''\n"
                                        "LABEL = '>20 cm'\nN = 'ape_cm_other'\n")
    _write(tmp_path, "spade/perf/code_shape.py", "MlflowClient(x); '> 20 cm'; 'ape_cm'\n")  # the instrument itself
    figures = measure(tmp_path, runs=1)
    # spade, spade.experiments, spade.experiments.tracking, .record (spade.train is __main__-less here: +1)
    assert figures["modules_imported_by_spade_train"] == 5
    assert figures["train_help_seconds"] > 0
    assert figures["lines_experiments"] == 4 + 1  # blank lines are not counted
    assert figures["lines_tracking"] == 4
    assert figures["lines_checks"] == 2
    assert figures["mlflow_client_constructions"] == 1
    assert figures["files_spelling_metric"]["ape_cm"] == 2  # record.py and train_checks.py, not 'ape_cm_other'
    assert figures["files_spelling_metric"]["over_20cm_rate"] == 1
    assert figures["tail_label_spellings"] == {"> 20 cm": 1, ">20 cm": 1}
    page = render(figures, figures, "abc", "def", "python -m spade.perf.code_shape --before abc", 1.0)
    assert "| `MlflowClient(` constructions | 1 | 1 |" in page and "- commits: before abc, after def" in page
