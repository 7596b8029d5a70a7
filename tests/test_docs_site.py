"""The documentation: the MkDocs site builds with ``--strict`` (a broken link, a missing page, an
API reference that fails or any other warning fails it), its generated references cover every config and entry
point, its nav holds every guide once (the ROS 2 deployment page included), the API reference agrees with the
signatures, the results pages render (lists as lists, figures one per line, titles in the index) and name no path
of the machine that wrote them, the site asks no third party for fonts, and the README stays a front page whose
links lead somewhere."""

from __future__ import annotations

import html
import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

REPO = Path(__file__).resolve().parents[1]
README = REPO / "README.md"
RESULTS = REPO / "docs" / "results"
# Absolute paths of a writing or building machine: none may reach a page (results pages print paths relative to
# the project or SPADE_HOME: spade.utils.provenance.shown_path).
MACHINE_PATHS = (str(REPO) + "/", "/work/", "/root/", "/tmp/pytest")


def _hook(name: str):  # noqa: ANN202  (a module)
    """A module of docs/hooks (not a package), imported by path."""
    spec = importlib.util.spec_from_file_location(f"docs_hook_{name}", REPO / "docs" / "hooks" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _nav() -> list[tuple[str, str]]:
    """mkdocs.yml's nav as (title, page) pairs, depth first (a section's index page has the section's title)."""
    def walk(items: list, section: str = "") -> list[tuple[str, str]]:
        out = []
        for item in items:
            if isinstance(item, str):
                out.append((section, item))
                continue
            for title, value in item.items():
                out += walk(value, title) if isinstance(value, list) else [(title, value)]
        return out

    return walk(yaml.safe_load((REPO / "mkdocs.yml").read_text())["nav"])


@pytest.fixture(scope="module")
def built(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    """The site built strictly once for this module's tests: (site folder, build log)."""
    site = tmp_path_factory.mktemp("docs") / "site"
    done = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(site)],
                          capture_output=True, text=True, timeout=110, cwd=REPO,
                          env={**os.environ, "NO_MKDOCS_2_WARNING": "1"})
    log = done.stdout + done.stderr
    assert done.returncode == 0, f"mkdocs build --strict failed (pip install -e '.[docs]'?):\n{log[-5000:]}"
    return site, log


@pytest.mark.slow  # a site build: a few seconds to a minute
@pytest.mark.timeout(120)
def test_the_site_builds_strictly_without_a_warning(built: tuple[Path, str]) -> None:
    site, log = built
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
    assert (site / "deployment" / "index.html").is_file()
    layout = site / "how-to" / "spade-foxglove-layout.json"  # the Foxglove layout, linked from the ROS 2 page
    assert layout.is_file() and not layout.is_symlink() and '"3D!spade"' in layout.read_text()
    assert 'href="../how-to/spade-foxglove-layout.json"' in (site / "deployment" / "index.html").read_text()


def _site_text(site: Path) -> dict[Path, str]:
    """Every page of the built site and its search index."""
    return {p: p.read_text(errors="replace") for p in sorted(site.rglob("*")) if p.suffix in (".html", ".json")}


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_the_built_site_names_no_path_of_the_writing_machine(built: tuple[Path, str]) -> None:
    site, _ = built
    for path, text in _site_text(site).items():
        for machine in MACHINE_PATHS:
            assert machine not in text, f"{path.relative_to(site)} names {machine}: a path of the writing machine"


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_the_site_requests_no_web_fonts(built: tuple[Path, str]) -> None:
    site, _ = built
    for path, text in _site_text(site).items():
        assert "fonts.googleapis.com" not in text and "fonts.gstatic.com" not in text, path.relative_to(site)


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_the_built_nav_holds_the_ros_page_and_one_entry_points(built: tuple[Path, str]) -> None:
    site, _ = built
    home = (site / "index.html").read_text()
    titles = [html.unescape(t) for t in re.findall(r'<span class="md-ellipsis">\s*(.*?)\s*</span>', home, re.S)]
    assert titles.count("Entry points") == 1, titles
    assert 'href="deployment/"' in home and any("ROS 2" in t for t in titles), titles


_DOC_HEADING = re.compile(r'<h[1-6] id="([^"]+)" class="doc doc-heading">')


def _text(fragment: str) -> str:
    return html.unescape(re.sub(r"<[^>]+>", "", fragment))


def _required_parameters(page: str) -> list[tuple[str, str, str]]:
    """(object, parameter, signature) for every parameter the page's tables mark *required*, with the signature of
    the object it documents (mkdocstrings: the heading's code; the table's last cell says ``required`` or gives the
    default)."""
    parts = _DOC_HEADING.split(page)
    found = []
    for ident, section in zip(parts[1::2], parts[2::2]):
        heading = section.split("</h", 1)[0]
        code = re.search(r'<code class="highlight language-python">(.*?)</code>', heading, re.S)
        signature = _text(code.group(1)) if code else ""
        for row in re.findall(r'<tr class="doc-section-item">(.*?)</tr>', section, re.S):
            if "<em>required</em>" in row:
                found.append((ident, _text(re.search(r"<code>(.*?)</code>", row, re.S).group(1)), signature))
    return found


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_no_parameter_is_marked_required_where_its_signature_gives_a_default(built: tuple[Path, str]) -> None:
    site, _ = built
    seen = []
    for page in sorted((site / "reference" / "api").glob("*/index.html")):
        for ident, name, signature in _required_parameters(page.read_text()):
            inner = signature[signature.find("(") + 1:signature.rfind(")")]
            parameters = re.findall(r"(?:^|,)\s*\**(\w+)", inner)
            defaults = re.findall(r"(\w+)\s*=", inner)
            assert name in parameters, f"{ident}: {name!r} is documented but not in its signature {signature}"
            assert name not in defaults, f"{ident}: {name!r} is marked required but {signature} gives a default"
            seen.append((ident, name))
    assert ("spade.planner.Planner", "model") in seen  # the check sees the tables (model has no default)
    planner = (site / "reference/api/planner/index.html").read_text()
    for name in ("threshold", "max_gap", "goal_tolerance_px", "disc_radius_m", "margin_m"):  # each its own row
        assert f"<code>{name}</code>" in planner, name


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_the_results_pages_render_lists_one_figure_a_line_and_an_index_by_title(built: tuple[Path, str]) -> None:
    site, _ = built
    index = (site / "results" / "index.html").read_text()
    hook = _hook("spade_docs")
    for page in sorted(RESULTS.glob("*.md")):
        if page.name == "README.md":
            continue
        links = [_text(t) for t in re.findall(rf'<a href="{re.escape(page.stem)}/">(.*?)</a>', index, re.S)]
        assert hook.page_title(page).replace("`", "") in links, f"the results index lists {page.name} by no title"
        text = (site / "results" / page.stem / "index.html").read_text()
        assert not re.search(r"<p>[^<]*:\n- ", text), f"{page.name}: a list rendered as one paragraph"
        assert not re.search(r"<td>[^<]*( / [^<]*){3,}</td>", text), f"{page.name}: a cell packing figures"
    guidance = (site / "results" / "guidance" / "index.html").read_text()
    assert "<p>Provenance:</p>\n<ul>" in guidance and "0.31&nbsp;±&nbsp;0.06<br>9.73&nbsp;±&nbsp;1.20" in guidance


def test_the_ros_deployment_page_is_in_the_nav_and_linked_from_the_readme_and_the_tutorial() -> None:
    nav = _nav()
    assert any(page == "deployment.md" and "ROS 2" in title for title, page in nav), nav
    assert "](docs/deployment.md)" in README.read_text()
    assert "](../deployment.md)" in (REPO / "docs" / "tutorials" / "deployment.md").read_text()


def test_the_nav_has_one_entry_points() -> None:
    titles = [title for title, _ in _nav()]
    assert titles.count("Entry points") == 1, titles


def test_the_committed_results_pages_render_and_name_no_path_of_the_writing_machine() -> None:
    """The pages in docs/results/ are written by code and committed: each list follows a blank line (Markdown
    starts no list inside a paragraph) and no absolute path of the machine that wrote it is left."""
    for page in sorted(RESULTS.glob("*.md")):
        lines = page.read_text().splitlines()
        for machine in MACHINE_PATHS:
            assert machine not in "\n".join(lines), f"{page.name} names {machine}"
        for before, line in zip(lines, lines[1:]):
            if line.startswith("- "):
                assert not before.strip() or before.startswith(("- ", "  ")), f"{page.name}: {line!r} follows no blank"


def test_the_hook_stacks_packed_figures_and_lists_pages_by_title(tmp_path: Path) -> None:
    hook = _hook("spade_docs")
    table = ("| row | L-shape: FID / APE (cm) / Hd19 / failures | seeds |\n|---|---|---|\n"
             "| BC | 0.31 ± 0.06 / 9.73 ± 1.20 / 5 ± 3 / 0.0% | 5 / 5 |\nprose a / b / c / d\n")
    assert hook.stack_figures(table) == (
        "| row | L-shape:<br>FID<br>APE (cm)<br>Hd19<br>failures | seeds |\n|---|---|---|\n"
        "| BC | 0.31&nbsp;±&nbsp;0.06<br>9.73&nbsp;±&nbsp;1.20<br>5&nbsp;±&nbsp;3<br>0.0% | 5 / 5 |\n"
        "prose a / b / c / d\n")
    (tmp_path / "README.md").write_text("# Results\n")
    (tmp_path / "b.md").write_text("Intro.\n\n## Sizing on your own map\n")
    (tmp_path / "a.md").write_text("no heading at all\n")
    listing = hook.results_listing(tmp_path, "README.md")
    assert listing.splitlines()[-2:] == ["- [a](a.md)", "- [Sizing on your own map](b.md)"]


def test_the_api_reference_splits_parameters_documented_together() -> None:
    split = _hook("griffe_rst_roles").split_shared_parameters
    doc = ("Summary, with a comma: not a parameter.\n\nArgs:\n    model: the file.\n    threshold, max_gap: options\n"
           "        of the extraction.\n    radius_m, margin_m (float): trained with.\n\nReturns:\n    a, b: kept.")
    assert split(doc) == ("Summary, with a comma: not a parameter.\n\nArgs:\n    model: the file.\n"
                          "    threshold: options\n        of the extraction.\n    max_gap: options\n"
                          "        of the extraction.\n    radius_m (float): trained with.\n"
                          "    margin_m (float): trained with.\n\nReturns:\n    a, b: kept.")


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


@pytest.mark.slow  # a site build and a browser
@pytest.mark.timeout(240)
def test_a_results_page_fits_its_column_in_a_browser(built: tuple[Path, str]) -> None:
    """The encoding results page (its tables are the widest) rendered by chromium at 1600x1000 and at a laptop's
    1280x800: nothing overflows the content column (the page does not scroll sideways, every table fits its
    column); a screenshot goes to ``test-artifacts/docs/`` (the folder is printed)."""
    from browser_support import ARTIFACTS, browser_page, chromium_path, screenshot

    chromium_path()
    site, _ = built
    page_file = site / "results" / "encoding" / "index.html"
    print(f"\nscreenshots: {(ARTIFACTS / 'docs').resolve()}")
    for width, height in ((1600, 1000), (1280, 800)):
        with browser_page(width=width, height=height) as page:
            page.goto(page_file.as_uri())
            page.wait_for_selector(".md-content table")
            widths = page.evaluate("""() => {
                const column = document.querySelector('.md-content');
                const tables = [...column.querySelectorAll('table')].map(t => {
                    const box = t.parentElement;  // material's scroll wrapper (overflow: auto)
                    return [t.scrollWidth, box.clientWidth, t.innerText.slice(0, 60)];
                });
                return {column: [column.scrollWidth, column.clientWidth],
                        page: [document.documentElement.scrollWidth, document.documentElement.clientWidth],
                        tables};
            }""")
            assert widths["page"][0] <= widths["page"][1], f"{width}px: the page scrolls sideways: {widths}"
            assert widths["column"][0] <= widths["column"][1], f"{width}px: the column overflows: {widths}"
            wide = [t for t in widths["tables"] if t[0] > t[1] + 1]
            assert not wide, f"{width}px: tables wider than the column (scrolled, cut): {wide}"
            screenshot(page, f"docs/results_encoding_{width}x{height}.png")
