"""MkDocs hook: reference pages generated from the repository at build time, never typed by hand.

A page that holds one of these markers gets it replaced by Markdown built from the sources:

- ``<!-- spade:config-reference -->``: every primary config of ``conf/`` (one per entry point) and every config
  group with its options, each with its keys, defaults and the comments beside them;
- ``<!-- spade:entry-points -->``: every ``python -m spade...`` entry point (the modules with a ``__main__``
  block), its console script from ``pyproject.toml`` and the first paragraph of its docstring.

- ``<!-- spade:findings PAGE ... -->``: the named results pages' findings (Home's result).

The results index (``docs/results/README.md``) gets a list of links to the pages beside it, each by its title (its
first heading) with its finding (the first sentence of its verdict), at build time only: the file itself is not changed. The results pages (files the code writes,
never edited by hand) get a compact layout on the site: a table cell that packs several figures ``a / b / c / d``
(the paper's layout, as the terminal and MLflow show it) shows them one per line.

So the reference follows ``conf/`` and the code: a new key or group appears on the next build.
"""

from __future__ import annotations

import ast
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
CONF = ROOT / "conf"
SWEEPS = ROOT / "sweeps"
SPADE = ROOT / "spade"

CONFIG_MARKER = "<!-- spade:config-reference -->"
FINDINGS_MARKER = re.compile(r"<!-- spade:findings ([\w ]+) -->")
"""Home's marker: ``<!-- spade:findings closed_loop teacher -->`` becomes each named results page's finding."""
ENTRY_MARKER = "<!-- spade:entry-points -->"

_KEY = re.compile(r"^(?P<indent>\s*)(?P<key>[A-Za-z_@/][\w.@/+-]*):(?:\s+(?P<rest>.*))?$")
_ITEM = re.compile(r"^(?P<indent>\s*)-\s+(?P<rest>.*)$")


# ------------------------------------------------------------------------------------------------------ parsing
def _split_comment(text: str) -> tuple[str, str]:
    """``value  # comment`` -> (value, comment); a ``#`` inside quotes or braces is not a comment."""
    quote, depth = "", 0
    for i, ch in enumerate(text):
        if quote:
            quote = "" if ch == quote else quote
        elif ch in "'\"":
            quote = ch
        elif ch in "[{":
            depth += 1
        elif ch in "]}":
            depth -= 1
        elif ch == "#" and depth <= 0 and (i == 0 or text[i - 1].isspace()):
            return text[:i].strip(), text[i + 1:].strip()
    return text.strip(), ""


def parse_config(path: Path) -> dict:
    """A config file's description (its leading comments), package, defaults list and keys.

    Keys are ``(dotted name, value as written, comment)``; a mapping key without a value of its own appears only
    when it carries a comment (its children carry the values). A comment on a line of its own continues the
    comment of the key above it only when nothing else came between.
    """
    lines = path.read_text().splitlines()
    description: list[str] = []
    package = None
    i = 0
    while i < len(lines) and (not lines[i].strip() or lines[i].lstrip().startswith("#")):
        text = lines[i].strip().lstrip("#").strip()
        if text.startswith("@package"):
            package = text.split(None, 1)[1] if " " in text else None
        elif text:
            description.append(text)
        i += 1
    keys: list[list[str]] = []
    defaults: list[tuple[str, str]] = []
    stack: list[tuple[int, str]] = []  # (indent, key)
    in_defaults = False
    last = None
    for line in lines[i:]:
        if not line.strip():
            last = None
            continue
        if line.lstrip().startswith("#"):
            if last is not None and last[2]:
                last[2] += " " + line.strip().lstrip("#").strip()
            continue
        item = _ITEM.match(line)
        if item:
            if in_defaults and not item.group("indent"):
                value, comment = _split_comment(item.group("rest"))
                defaults.append((value, comment))
            last = None
            continue
        m = _KEY.match(line)
        if not m:
            last = None
            continue
        indent = len(m.group("indent"))
        key = m.group("key")
        value, comment = _split_comment(m.group("rest") or "")
        while stack and stack[-1][0] >= indent:
            stack.pop()
        in_defaults = indent == 0 and key == "defaults"
        if in_defaults:
            last = None
            continue
        dotted = ".".join([k for _, k in stack] + [key])
        stack.append((indent, key))
        if value or comment:
            last = [dotted, value, comment]
            keys.append(last)
        else:
            last = None
    return {"description": " ".join(description), "package": package, "defaults": defaults, "keys": keys}


# ---------------------------------------------------------------------------------------------------- rendering
_CODE_SPAN = re.compile(r"(`+)(.+?)\1")


_MARKDOWN = re.compile(r"([\\*_\[\]|])")


def _escape(text: str) -> str:
    """Plain text: Markdown's specials escaped (``[a] [b]`` is no link, ``*_L`` no emphasis), HTML's quoted."""
    return _MARKDOWN.sub(r"\\\1", text).replace("<", "&lt;").replace(">", "&gt;")


def _cell(text: str) -> str:
    """Text for a table cell, escaped outside code spans (inside them everything is literal)."""
    out, pos = [], 0
    for m in _CODE_SPAN.finditer(text):
        out += [_escape(text[pos:m.start()]), m.group(0)]
        pos = m.end()
    return "".join(out) + _escape(text[pos:])


def _code(text: str) -> str:
    if not text:
        return ""
    fence = "``" if "`" in text else "`"
    pad = " " if "`" in text else ""
    return f"{fence}{pad}{text}{pad}{fence}"


def _key_table(keys: list[list[str]]) -> list[str]:
    if not keys:
        return ["*(no keys of its own)*", ""]
    out = ["| key | default | what it does |", "|---|---|---|"]
    out += [f"| {_code(k)} | {_code(v)} | {_cell(c)} |" for k, v, c in keys]
    return out + [""]


def _defaults_line(defaults: list[tuple[str, str]]) -> list[str]:
    if not defaults:
        return []
    shown = ", ".join(_code(v) for v, _ in defaults)
    return [f"Defaults list: {shown}.", ""]


def _relative(path: Path) -> str:
    return path.relative_to(ROOT).as_posix()


def _groups(base: Path) -> list[str]:
    """Every group (a folder of yaml files) under ``base``: its options, then each option's keys."""
    out: list[str] = []
    for group in sorted(p for p in base.rglob("*") if p.is_dir() and any(p.glob("*.yaml"))):
        name = group.relative_to(base).as_posix()
        options = sorted(group.glob("*.yaml"))
        parsed = {p: parse_config(p) for p in options}
        out += [f"### `{name}`", "", "| option | what it is |", "|---|---|"]
        out += [f"| {_code(p.stem)} | {_cell(parsed[p]['description'])} |" for p in options]
        out.append("")
        if name == "experiment":  # experiments override other groups' keys; their own files list the overrides
            out += ["Each experiment is a `# @package _global_` file that overrides the groups above for one row "
                    "of a table (or, for `table1`, `ablation_*`, `guidance`, a whole table as a multirun); read "
                    "the file for its overrides.", ""]
            continue
        for p in options:
            cfg = parsed[p]
            if not cfg["keys"] and not cfg["defaults"]:
                continue
            package = f" (package `{cfg['package']}`)" if cfg["package"] else ""
            out += [f"#### `{name}={p.stem}`", "", f"`{_relative(p)}`{package}", ""]
            out += _defaults_line(cfg["defaults"]) + _key_table(cfg["keys"])
    return out


def config_reference() -> str:
    out: list[str] = ["## Primary configs", "",
                      "One per entry point (`conf/<name>.yaml`); `key=value` on the command line sets a key, "
                      "`group=option` picks a group's option.", ""]
    for path in sorted(CONF.glob("*.yaml")):
        cfg = parse_config(path)
        out += [f"### `{path.stem}`", "", f"`{_relative(path)}`" + (f": {_cell(cfg['description'])}" if
                                                                      cfg["description"] else ""), ""]
        out += _defaults_line(cfg["defaults"]) + _key_table(cfg["keys"])
    out += ["## Config groups", "",
            "A group is a folder of `conf/`; `GROUP=OPTION` picks one of its files (`+experiment=NAME` for the "
            "experiments, which override other groups).", ""]
    out += _groups(CONF)
    out += ["## Sweep groups", "",
            "Groups of `sweeps/`, added to `python -m spade.train` with `--config-dir sweeps` (the Hydra plugins "
            "of the `sweeps` extra); see [Sweeps](../how-to/sweeps.md).", ""]
    out += _groups(SWEEPS)
    return "\n".join(out)


def _entry_modules() -> list[str]:
    found = []
    for path in sorted(SPADE.rglob("*.py")):
        if '__name__ == "__main__"' in path.read_text():
            rel = path.relative_to(ROOT).with_suffix("")
            parts = rel.parts[:-1] if rel.name == "__main__" else rel.parts  # spade/ros/__main__.py: python -m spade.ros
            found.append(".".join(parts))
    top = [m for m in found if m.count(".") == 1]
    return top + [m for m in found if m.count(".") > 1]


def _scripts() -> dict[str, str]:
    """Console scripts of pyproject.toml: target module -> script name."""
    try:
        import tomllib
    except ModuleNotFoundError:  # Python 3.10
        import tomli as tomllib  # type: ignore[no-redef]
    data = tomllib.loads((ROOT / "pyproject.toml").read_text())
    out: dict[str, str] = {}
    for name, target in data.get("project", {}).get("scripts", {}).items():
        module = target.split(":")[0]
        attr = target.split(":")[1] if ":" in target else ""
        out[_script_module(module, attr)] = name
    return out


def _script_module(module: str, attr: str) -> str:
    """The ``python -m`` module a console script stands for (``spade.cli:plan`` -> ``spade.plan``,
    ``spade.ros.__main__:cli`` -> ``spade.ros``)."""
    module = module.removesuffix(".__main__")
    if module == "spade.cli":
        source = (SPADE / "cli.py").read_text()
        m = re.search(rf"^{re.escape(attr)}\s*=\s*_module\(\"([\w.]+)\"\)", source, re.M)
        if m:
            return m.group(1)
    return module


def _first_paragraph(doc: str) -> str:
    """The docstring's first paragraph as Markdown (Sphinx roles such as ``:mod:`x``` become code spans)."""
    para = " ".join(line.strip() for line in doc.strip().split("\n\n")[0].splitlines())
    return re.sub(r":(?:py:)?(?:mod|class|func|meth|data|attr|exc):`~?([^`]+)`", r"`\1`", para)


def entry_points() -> str:
    scripts = _scripts()
    out = ["| command | console script | config | what it does |", "|---|---|---|---|"]
    for module in _entry_modules():
        path = ROOT / (module.replace(".", "/") + ".py")
        if not path.is_file():
            path = ROOT / module.replace(".", "/") / "__main__.py"
        tree = ast.parse(path.read_text())
        doc = _first_paragraph(ast.get_docstring(tree) or "")
        config = ""
        m = re.search(r'config_name="(\w+)"', path.read_text())
        if m and (CONF / f"{m.group(1)}.yaml").is_file():
            config = f"[`conf/{m.group(1)}.yaml`](configuration.md#{m.group(1)})"
        script = _code(scripts.get(module, ""))
        out.append(f"| `python -m {module}` | {script} | {config} | {_cell(doc)} |")
    return "\n".join(out) + "\n"


def page_title(path: Path) -> str:
    """A page's title: its first heading (``#`` or ``##``...), its file name's stem when it has none."""
    for line in path.read_text().splitlines():
        if line.startswith("#"):
            return line.lstrip("#").strip()
    return path.stem


def page_finding(path: Path, whole: bool = False) -> str:
    """A results page's one-line finding: the first sentence of the verdict that follows its title (a ``## Verdict``
    heading and the lost-store notice, a ``>`` line, are passed over; a verdict list gives its first item).
    ``whole``: the verdict's whole first paragraph (Home). Every results page leads with its verdict (tests/test_docs_site.py checks it), so the index and Home quote the
    pages rather than restate them."""
    lines = path.read_text().splitlines()
    if not lines or not lines[0].startswith("# "):
        return ""
    for line in lines[1:]:
        text = line.strip()
        if not text or text.startswith(">") or text.startswith("## "):
            continue
        if text.startswith(("|", "#", "!", "???")):
            return ""
        text = re.sub(r"\*\*([^*]+)\*\*", r"\1", text.removeprefix("- "))
        if whole:
            return text
        sentence = re.match(r"(.+?[.!?])(?:\s|$)(?![^(]*\))", text)
        return (sentence.group(1) if sentence else text).strip()
    return ""


def results_listing(results_dir: Path, index: str) -> str:
    """Links to every results page beside the index, each by its title and with its one-line finding
    (:func:`page_finding`; the pages are written by spade.report, spade.critic...)."""
    lines = ["", "## Pages", ""]
    for path in sorted(results_dir.glob("*.md")):
        if path.name != index:
            finding = page_finding(path)
            lines.append(f"- [{_cell(page_title(path))}]({path.name})" + (f": {finding}" if finding else ""))
    return "\n".join(lines) + "\n"


def findings(results_dir: Path, pages: list[str], link: str = "results/") -> str:
    """Home's result: each named results page's finding, linked to its page (generated, never typed)."""
    out = []
    for name in pages:
        path = results_dir / f"{name}.md"
        if path.is_file() and page_finding(path):
            out.append(f"- **[{_cell(page_title(path))}]({link}{name}.md)**: {page_finding(path, whole=True)}")
    return "\n".join(out) + "\n"


_TABLE_CELL = re.compile(r"(?<!\\)\|")
STACKED_FIGURES = 4  # a cell of this many " / "-separated figures or more shows them one per line


def _stacked(cell: str) -> str:
    """``a / b / c / d`` -> ``a<br>b<br>c<br>d``, ``x ± y`` never broken across lines; a header's
    ``label: a / b / ...`` keeps its label on a line of its own; a cell of fewer figures (``5 / 5`` seeds) is left as
    it is."""
    parts = cell.strip().split(" / ")
    if len(parts) < STACKED_FIGURES:
        return cell
    label, colon, first = parts[0].rpartition(": ")
    if colon:
        parts = [label + ":", first, *parts[1:]]
    return " " + "<br>".join(part.replace(" ± ", "&nbsp;±&nbsp;") for part in parts) + " "


def stack_figures(markdown: str) -> str:
    """The results pages' compact layout: every table cell that packs several figures shows them one per line, so
    that a table fits the column (a table still wider scrolls sideways in it: the theme's own style); everything
    outside tables is left as it is."""
    out = []
    for line in markdown.splitlines():
        if line.startswith("|") and not re.fullmatch(r"[|:\- ]+", line):
            line = "|".join(_stacked(cell) for cell in _TABLE_CELL.split(line))
        out.append(line)
    return "\n".join(out) + ("\n" if markdown.endswith("\n") else "")


# --------------------------------------------------------------------------------------------------------- hook
def on_page_markdown(markdown: str, page, config, files) -> str:  # noqa: ANN001  (MkDocs' hook signature)
    src = Path(page.file.src_uri)
    if src.parent.as_posix() == "results" and src.name in ("README.md", "index.md"):
        # The results pages are files the code writes (never edited by hand): the site links each of them here, at
        # build time, so that a new page needs no edit of the index or of mkdocs.yml.
        markdown += results_listing(Path(config["docs_dir"]) / "results", src.name)
    elif src.parent.as_posix() == "results":
        markdown = stack_figures(markdown)
    for match in list(FINDINGS_MARKER.finditer(markdown)):
        markdown = markdown.replace(match.group(0), findings(Path(config["docs_dir"]) / "results",
                                                              match.group(1).split()))
    if CONFIG_MARKER in markdown:
        markdown = markdown.replace(CONFIG_MARKER, config_reference())
    if ENTRY_MARKER in markdown:
        markdown = markdown.replace(ENTRY_MARKER, entry_points())
    return markdown


if __name__ == "__main__":  # print the generated Markdown, for a look without building the site
    print(config_reference() if sys.argv[1:] == ["config"] else entry_points())
