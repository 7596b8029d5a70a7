"""The package's floors: no module imports a package on a higher floor, at module level or inside a function;
no import cycle runs between spade packages at module level; and no import cycle runs between spade modules at all,
counting the imports inside functions.

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
    {"config"},  # the commands' config checks, before any work
    {"tracking"},  # a run's MLflow record and the paper's tables as MLflow experiments
    {"experiments"},  # runs, evaluations and results pages
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


def module_imports(sources: dict[str, tuple[str, bool]]) -> dict[str, dict[str, list[int]]]:
    """The spade modules each module of ``sources`` (module -> (source, is package)) imports, anywhere in it but
    under ``if TYPE_CHECKING:``: {importer: {imported: [lines]}}. ``from spade.x import y`` imports the module
    ``spade.x.y`` where that is a module, else ``spade.x``; ``import spade.x.y.z`` of a name below a module is the
    module."""
    known = set(sources)
    graph: dict[str, dict[str, list[int]]] = {}

    def add(importer: str, name: str, line: int) -> None:
        parts = name.split(".")
        while parts and ".".join(parts) not in known:
            parts.pop()
        target = ".".join(parts)
        if target and target != importer:
            graph.setdefault(importer, {}).setdefault(target, []).append(line)

    for module, (source, is_package) in sources.items():
        package = module.split(".") if is_package else module.split(".")[:-1]

        def visit(node: ast.AST, module: str = module, package: list[str] = package) -> None:
            if isinstance(node, ast.If) and _is_type_checking(node.test):
                for child in node.orelse:
                    visit(child)
                return
            if isinstance(node, ast.Import):
                for alias in node.names:
                    if alias.name.split(".")[0] == "spade":
                        add(module, alias.name, node.lineno)
            elif isinstance(node, ast.ImportFrom):
                base = ".".join([*package[: len(package) - node.level + 1], *([node.module] if node.module else [])]
                                ) if node.level else (node.module or "")
                if base.split(".")[0] == "spade":
                    for alias in node.names:
                        add(module, f"{base}.{alias.name}" if f"{base}.{alias.name}" in known else base, node.lineno)
            for child in ast.iter_child_nodes(node):
                visit(child)

        visit(ast.parse(source, module))
    return graph


def module_cycles(graph: dict[str, dict[str, list[int]]]) -> list[set[str]]:
    """The strongly connected components of more than one module of ``graph`` (Tarjan's, iteratively)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    cycles: list[set[str]] = []
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph.get(root, {}))))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph.get(child, {})))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = set()
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.add(member)
                    if member == node:
                        break
                if len(component) > 1:
                    cycles.append(component)
    return cycles


def spade_module_graph() -> dict[str, dict[str, list[int]]]:
    return module_imports({module_name(path): (path.read_text(), path.name == "__init__.py")
                           for path in sorted(PACKAGE.rglob("*.py"))})


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
    source = PACKAGE / "train.py"  # the entry point defers the run's import to its main
    assert ("spade.experiments.run", False) in [(name, at_import) for name, _, at_import in spade_imports(source)]
    assert floor_of("spade.annotation.run") > floor_of("spade.data.writer") > floor_of("spade.maps.frame")
    assert floor_of("spade.train") == TOP and floor_of("spade") == TOP and floor_of("spade.utils.config") == 0


def test_no_import_cycle_between_modules() -> None:
    """No two spade modules import each other, directly or around a loop, even through imports inside functions."""
    graph = spade_module_graph()
    cycles = module_cycles(graph)

    def describe(cycle: set[str]) -> str:
        return "\n".join(f"  {a} -> {b} (line {', '.join(map(str, lines))})" for a in sorted(cycle)
                         for b, lines in sorted(graph[a].items()) if b in cycle)

    assert not cycles, "spade modules that import each other (move the shared piece down to a module both import):\n" + (
        "\n\n".join(describe(c) for c in cycles))


def test_the_cycle_checker_counts_function_level_imports() -> None:
    sources = {
        "spade.ros.node": ("from spade.ros import messages\n"
                           "def make():\n    from spade.ros.action import Server\n", False),
        "spade.ros.action": ("def qos():\n    from spade.ros.node import make_qos\n", False),
        "spade.ros.messages": ("from typing import TYPE_CHECKING\n"
                               "if TYPE_CHECKING:\n    from spade.ros.node import X\n", False),
        "spade.ros": ("", True),
    }
    graph = module_imports(sources)
    assert graph["spade.ros.node"] == {"spade.ros.messages": [1], "spade.ros.action": [3]}
    assert "spade.ros.messages" not in graph  # under TYPE_CHECKING: never runs
    assert module_cycles(graph) == [{"spade.ros.action", "spade.ros.node"}]


def test_no_package_defers_its_names() -> None:
    """No module-level ``__getattr__`` (PEP 562) hands out names on first use: a name is imported from the module
    that defines it, so that what a module loads is what its imports say."""
    found = []
    for path in sorted(PACKAGE.rglob("*.py")):
        for node in ast.parse(path.read_text()).body:
            targets = (node.targets if isinstance(node, ast.Assign) else [node] if isinstance(node, ast.FunctionDef)
                       else [])
            if any(getattr(t, "id", getattr(t, "name", None)) == "__getattr__" for t in targets):
                found.append(f"{path.relative_to(PACKAGE.parent)}:{node.lineno}")
    assert not found, f"module __getattr__ (import the names from their modules instead): {found}"


def test_imports_run_at_module_level() -> None:
    """SPADE's imports sit at the top of their modules, where a reader sees what a module needs; the few left inside
    functions are an entry point's deferral in its ``main`` (what keeps ``--help`` fast), an optional dependency (the
    ROS middleware, the web server), or what a torch-free module (the deploy planner, the ROS node, the checks) needs
    only on its training-stack path. A ceiling, so that deferring imports does not creep back."""
    inside = [f"{path.relative_to(PACKAGE.parent)}:{line}" for path in sorted(PACKAGE.rglob("*.py"))
              for _, line, at_import in spade_imports(path) if not at_import]
    assert len(inside) <= 100, f"{len(inside)} spade imports inside functions (at most 100): {inside}"
