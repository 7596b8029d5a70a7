"""The documentation (issue 33): the MkDocs site builds with ``--strict`` (a broken link, a missing page, an API
reference that fails or any other warning fails it), its generated references cover every config and entry point,
and the README stays a front page whose links lead somewhere."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
README = REPO / "README.md"


@pytest.mark.slow  # a site build: a few seconds to a minute
@pytest.mark.timeout(120)
def test_the_site_builds_strictly_without_a_warning(tmp_path: Path) -> None:
    site = tmp_path / "site"
    done = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(site)],
                          capture_output=True, text=True, timeout=110, cwd=REPO,
                          env={**os.environ, "NO_MKDOCS_2_WARNING": "1"})
    log = done.stdout + done.stderr
    assert done.returncode == 0, f"mkdocs build --strict failed (pip install -e '.[docs]'?):\n{log[-5000:]}"
    assert not re.search(r"^(WARNING|ERROR)\b", log, re.M), log[-5000:]
    for page in ("getting-started", "tutorials/own-map", "tutorials/sketching", "tutorials/paper-table",
                 "tutorials/deployment", "how-to/scale-out", "how-to/sweeps", "how-to/resume",
                 "reference/configuration", "reference/entry-points", "reference/dataset-format",
                 "reference/model-files", "reference/metrics", "method", "results", "reference/api/planner"):
        assert (site / page / "index.html").is_file(), f"no page {page}"
    # The generated references cover what is in conf/ and every python -m entry point.
    config = (site / "reference/configuration/index.html").read_text()
    for path in sorted((REPO / "conf").glob("*.yaml")):  # every primary config
        assert f"conf/{path.name}" in config, f"{path} missing from the reference"
    for path in sorted((REPO / "conf").rglob("*/*.yaml")):  # every group and option
        group = path.parent.relative_to(REPO / "conf").as_posix()
        assert f"<code>{group}</code>" in config and f"<code>{path.stem}</code>" in config, f"{path} missing"
    entries = (site / "reference/entry-points/index.html").read_text()
    for module in ("train", "evaluate", "annotate", "report", "plan", "export", "sketch", "bench", "data.verify"):
        assert f"python -m spade.{module}" in entries and (module == "data.verify" or f"spade-{module}" in entries)
    assert 'id="spade.planner.Planner"' in (site / "reference/api/planner/index.html").read_text()


def test_the_readme_is_a_front_page_whose_links_resolve() -> None:
    text = README.read_text()
    assert len(text.splitlines()) <= 200
    assert not re.search(r"\b20\d\d-\d\d-\d\d\b", text), "dated notes belong in no README"
    assert not re.search(r"\b(I|me|my|mine)\b", text), "first person belongs in no README"
    assert "make quickstart" in text and "make test" in text
    links = re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", text)
    assert links
    for link in links:
        if not re.match(r"[a-z]+://", link):
            assert (REPO / link).exists(), f"README links to {link}, which does not exist"
