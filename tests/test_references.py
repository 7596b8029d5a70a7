"""Code, configs and docs cite only what the repository holds: no ``DESIGN.md`` (the method is docs/method.md), no
issue numbers of a tracker the repository does not carry, and no repository path (``spade/...py``,
``conf/...yaml``, ``docs/...md``) that does not exist."""

from __future__ import annotations

import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SCANNED = ("spade", "conf", "docs")
SUFFIXES = {".py", ".yaml", ".yml", ".md", ".html", ".js", ".css", ".toml", ".txt"}

# Known findings that are still to be fixed, as (file, the citation as it is reported below). Empty this list as they
# are fixed; nothing new goes in.
ALLOWED: set[tuple[str, str]] = set()

DESIGN = re.compile(r"DESIGN\.md")
ISSUE = re.compile(r"\b[Ii]ssues?\s+#?\d+|\(#\d+\)")
PATH = re.compile(r"(?<![\w/.-])(?:spade|conf|docs)/[\w./-]*?\w\.(?:py|yaml|md)(?![\w])")


def scanned_files() -> list[Path]:
    return sorted(p for top in SCANNED for p in (REPO / top).rglob("*")
                  if p.is_file() and p.suffix in SUFFIXES and "__pycache__" not in p.parts)


def citations(text: str) -> list[tuple[int, str]]:
    """(line, citation) of every DESIGN.md, issue-number and missing-path citation in ``text``."""
    found = []
    for number, line in enumerate(text.splitlines(), 1):
        found += [(number, m.group()) for m in DESIGN.finditer(line)]
        found += [(number, m.group()) for m in ISSUE.finditer(line)]
        found += [(number, m.group()) for m in PATH.finditer(line) if not (REPO / m.group()).exists()]
    return found


def findings() -> list[tuple[str, int, str]]:
    out = []
    for path in scanned_files():
        try:
            text = path.read_text(encoding="utf-8")
        except UnicodeDecodeError:
            continue
        rel = path.relative_to(REPO).as_posix()
        out += [(rel, line, cited) for line, cited in citations(text)]
    return out


def test_the_scan_finds_each_kind_of_citation() -> None:
    text = ("see DESIGN.md section 4\n(issue 47 item 3)\nissues 32 and 33\nfixed in (#49)\n"
            "spade/models/presets.py\nconf/scale/cpu.yaml\nconf/experiment/<row>.yaml\n")
    assert [cited for _, cited in citations(text)] == [
        "DESIGN.md", "issue 47", "issues 32", "(#49)", "spade/models/presets.py"]


def test_no_citation_of_what_the_repository_does_not_hold() -> None:
    found = findings()
    new = [f"{rel}:{line}: {cited}" for rel, line, cited in found if (rel, cited) not in ALLOWED]
    assert not new, ("cite docs/method.md, a docs page or the module that holds the thing instead of:\n"
                     + "\n".join(new))


def test_the_allow_list_holds_only_findings_still_there() -> None:
    found = {(rel, cited) for rel, _, cited in findings()}
    assert not ALLOWED - found, f"fixed, so remove from ALLOWED: {sorted(ALLOWED - found)}"
