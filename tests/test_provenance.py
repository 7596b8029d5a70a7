"""spade.utils.provenance: what a results page states about where it comes from, and how it shows a path (relative
to the project or SPADE_HOME, never the writing machine's absolute path)."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from spade.utils import provenance
from spade.utils.provenance import REPO_ROOT, command_line, shown_path


@pytest.fixture
def home(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A SPADE_HOME outside the repository, the current directory elsewhere again."""
    home = tmp_path / "home"
    (tmp_path / "elsewhere").mkdir()
    monkeypatch.setenv("SPADE_HOME", str(home))
    monkeypatch.chdir(tmp_path / "elsewhere")
    return home


def test_an_absolute_path_under_the_repository_or_spade_home_is_shown_relative(home: Path) -> None:
    assert shown_path(str(REPO_ROOT / "logs" / "mlflow.db")) == "logs/mlflow.db"
    assert shown_path(REPO_ROOT / "data" / "quickstart" / "test") == "data/quickstart/test"  # a Path too
    assert shown_path(f"{home}/logs/reports/guidance.md") == "logs/reports/guidance.md"
    assert shown_path(str(Path.cwd() / "out" / "page.md")) == "out/page.md"
    assert shown_path(str(REPO_ROOT)) == "."


def test_a_tracking_uri_keeps_its_scheme_with_the_path_relative(home: Path) -> None:
    assert shown_path(f"sqlite:///{REPO_ROOT}/logs/mlflow.db") == "sqlite:///logs/mlflow.db"
    assert shown_path(f"sqlite:///{home}/logs/mlflow.db") == "sqlite:///logs/mlflow.db"
    assert shown_path(f"file://{home}/mlruns") == "mlruns"


@pytest.mark.parametrize("text", ["logs/mlflow.db", "sqlite:///logs/mlflow.db", "http://mlflow.lab:5000",
                                  "databricks", "/srv/shared/spade/mlflow.db", "sqlite:////srv/shared/mlflow.db",
                                  "models:/spade-student@champion", ""])
def test_anything_else_is_left_as_it_is(home: Path, text: str) -> None:
    assert shown_path(text) == text


def test_spade_home_wins_over_the_repository_when_it_lies_inside_it(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("SPADE_HOME", str(REPO_ROOT / "home"))
    assert shown_path(str(REPO_ROOT / "home" / "logs" / "mlflow.db")) == "logs/mlflow.db"
    assert shown_path(str(REPO_ROOT / "logs" / "mlflow.db")) == "logs/mlflow.db"
    monkeypatch.delenv("SPADE_HOME")
    assert provenance.shown_roots()[0] == REPO_ROOT


def test_the_command_line_shows_its_paths_relative(home: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(sys, "argv", ["report.py", f"tracking_uri=sqlite:///{home}/logs/mlflow.db",
                                      f"output_dir={REPO_ROOT}/docs/results", "scale=quickstart", "note=a b"])
    assert command_line("spade.report") == ("python -m spade.report tracking_uri=sqlite:///logs/mlflow.db "
                                            "output_dir=docs/results scale=quickstart 'note=a b'")
