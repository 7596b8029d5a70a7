"""The package's floors: no module imports a package on a higher floor, at module level or inside a function;
and no import cycle runs between spade packages at module level.

Read from the source (AST), so a function-level import that only runs on some path counts as much as one at the
top of a file (one home per concept: code that a lower floor needs lives on that floor).
"""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "spade"

# Lowest first; a package may import its own floor and any lower one. ``paths`` (the repository's folders) and
# ``utils`` are dependency-free helpers; the top-level ``spade.X`` entry points sit above everything.
FLOORS = [
    {"utils", "paths"},
    {"maps"},
    {"models"},
    {"data"},
    {"metrics"},
    {"annotation"},
    {"training"},
    {"deploy"},
    {"ros"},
    {"closedloop"},
    {"sketching"},
    {"experiments", "tracking",  # a run's MLflow record: imported by experiments, reads their tables
     "config"},  # the commands' config checks: imported by experiments' runs, the report's checks read its tables
    {"perf"},
]
TOP = len(FLOORS)  # spade/*.py entry points and spade/__init__.py

def floor_of(module: str) -> int:
    """The floor of ``spade.<package>...`` (the top for the entry points ``spade.X`` and ``spade`` itself)."""
    parts = module.split(".")
    if len(parts) < 2:
        return TOP
    for level, packages in enumerate(FLOORS):
        if parts[1] in packages:
            return level
    if (PACKAGE / f"{parts[1]}.py").is_file():
        return TOP
    raise AssertionError(f"{module}: package spade.{parts[1]} has no floor; add it to FLOORS")


def module_name(path: Path) -> str:
    rel = path.relative_to(PACKAGE.parent).with_suffix("")
    parts = rel.parts[:-1] if rel.name == "__init__" else rel.parts
    return ".".join(parts)


def imports_in(source: str, module: str, is_package: bool = False, filename: str = "<source>"
               ) -> list[tuple[str, int, bool]]:
    """Every ``spade.*`` module that ``source`` (the text of module ``module``) imports, absolute or relative,
    anywhere in it: (imported module, line, whether it runs at import time). Imports inside a function (or a
    lambda) run later; those under ``if TYPE_CHECKING:`` never do."""
    package = module.split(".") if is_package else module.split(".")[:-1]
    out: list[tuple[str, int, bool]] = []

    def visit(node: ast.AST, at_import: bool) -> None:
        if isinstance(node, ast.Import):
            out.extend((alias.name, node.lineno, at_import) for alias in node.names
                       if alias.name.split(".")[0] == "spade")
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[: len(package) - node.level + 1]
                name = ".".join([*base, node.module] if node.module else base)
            else:
                name = node.module or ""
            if name.split(".")[0] == "spade":
                out.append((name, node.lineno, at_import))
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
            at_import = False
        for child in ast.iter_child_nodes(node):
            runs = at_import and not (isinstance(node, ast.If) and _is_type_checking(node.test) and child in node.body)
            visit(child, runs)

    visit(ast.parse(source, filename), True)
    return out


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def spade_imports(path: Path) -> list[tuple[str, int, bool]]:
    """Every ``spade.*`` module the file ``path`` imports (:func:`imports_in`)."""
    return imports_in(path.read_text(), module_name(path), path.name == "__init__.py", str(path))


def upward_imports() -> dict[tuple[str, str], list[str]]:
    found: dict[tuple[str, str], list[str]] = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        importer = module_name(path)
        for imported, line, _ in spade_imports(path):
            if floor_of(imported) > floor_of(importer):
                found.setdefault((importer, imported), []).append(f"{path.relative_to(PACKAGE.parent)}:{line}")
    return found


def package_of(module: str) -> str:
    """``spade.<package>`` of a module (``spade.X`` itself for an entry point ``spade/X.py``)."""
    return ".".join(module.split(".")[:2])


def package_cycles() -> list[list[str]]:
    """The import cycles between spade packages at module level (strongly connected components of more than one
    package, each sorted), from the imports that run at import time."""
    graph: dict[str, set[str]] = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        importer = package_of(module_name(path))
        for imported, _, at_import in spade_imports(path):
            if at_import and package_of(imported) not in (importer, "spade"):
                graph.setdefault(importer, set()).add(package_of(imported))
    # Tarjan's strongly connected components
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    cycles: list[list[str]] = []

    def connect(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        for nxt in sorted(graph.get(node, ())):
            if nxt not in index:
                connect(nxt)
                low[node] = min(low[node], low[nxt])
            elif nxt in stack:
                low[node] = min(low[node], index[nxt])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                cycles.append(sorted(component))

    for node in sorted(graph):
        if node not in index:
            connect(node)
    return cycles


def test_every_package_has_a_floor() -> None:
    for path in PACKAGE.iterdir():
        if path.is_dir() and (path / "__init__.py").is_file():
            floor_of(f"spade.{path.name}")


def test_no_module_imports_a_higher_floor() -> None:
    found = upward_imports()
    assert not found, "imports that reach a higher floor (move the code they need down to the importer's floor):\n" + (
        "\n".join(f"  {a} -> {b} at {', '.join(where)}" for (a, b), where in sorted(found.items())))


def test_no_import_cycle_between_packages() -> None:
    cycles = package_cycles()
    assert not cycles, f"spade packages that import each other at module level: {cycles}"


def test_the_checker_sees_function_level_imports() -> None:
    source = (
        "from typing import TYPE_CHECKING\n"
        "from spade.maps import FREE\n"
        "from . import format\n"
        "if TYPE_CHECKING:\n"
        "    from spade.models import modelfile\n"
        "class Module:\n"
        "    from spade.utils import timing\n"
        "    def prepare(self):\n"
        "        from ..experiments.run import train\n"
        "        import spade.annotation.run\n"
    )
    assert imports_in(source, "spade.data.datamodule") == [
        ("spade.maps", 2, True), ("spade.data", 3, True), ("spade.models", 5, False),
        ("spade.utils", 7, True), ("spade.experiments.run", 9, False), ("spade.annotation.run", 10, False)]
    assert floor_of("spade.experiments.run") > floor_of("spade.data.datamodule")  # so it would fail the floors
    source = PACKAGE / "metrics" / "baselines.py"
    assert ("spade.maps.costmap", False) in [(name, at_import) for name, _, at_import in spade_imports(source)]
    assert floor_of("spade.annotation.run") > floor_of("spade.data.writer") > floor_of("spade.maps.frame")
    assert floor_of("spade.train") == TOP and floor_of("spade") == TOP and floor_of("spade.utils.config") == 0
