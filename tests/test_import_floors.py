"""The package's floors: no module imports a package on a higher floor, at module level or inside a function.

Read from the source (AST), so a function-level import that only runs on some path counts as much as one at the
top of a file. ``KNOWN_UPWARD`` lists the imports that still reach up (issue 19, "One home per concept"): a new
one fails this test, and so does an entry that no longer occurs (remove it from the list when you fix it).
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
    {"sketching"},
    {"experiments"},
    {"perf"},
]
TOP = len(FLOORS)  # spade/*.py entry points and spade/__init__.py

# (importing module, imported module) pairs that still reach up a floor.
KNOWN_UPWARD = {
    ("spade.annotation.run", "spade.experiments.config"),
    ("spade.data.datamodule", "spade.annotation.run"),
    ("spade.data.datamodule", "spade.experiments.config_checks"),
    ("spade.data.verify", "spade.experiments.config_checks"),
    ("spade.data.writer", "spade.annotation.frame"),
    ("spade.metrics.baselines", "spade.annotation.execution"),
    ("spade.metrics.baselines", "spade.annotation.rasterize"),
    ("spade.metrics.decoding", "spade.annotation.execution"),
    ("spade.metrics.shape_paths", "spade.annotation.rasterize"),
    ("spade.metrics.train_shape_features", "spade.annotation.run"),
    ("spade.models.modelfile", "spade.data.format"),
    ("spade.sketching.workspace", "spade.experiments.config"),
}


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


def spade_imports(path: Path) -> list[tuple[str, int]]:
    """Every ``spade.*`` module ``path`` imports (absolute or relative, anywhere in the file), with its line."""
    out = []
    package = module_name(path).split(".")
    if path.name != "__init__.py":
        package = package[:-1]
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            out += [(alias.name, node.lineno) for alias in node.names if alias.name.split(".")[0] == "spade"]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[: len(package) - node.level + 1]
                name = ".".join([*base, node.module] if node.module else base)
            else:
                name = node.module or ""
            if name.split(".")[0] == "spade":
                out.append((name, node.lineno))
    return out


def upward_imports() -> dict[tuple[str, str], list[str]]:
    found: dict[tuple[str, str], list[str]] = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        importer = module_name(path)
        for imported, line in spade_imports(path):
            if floor_of(imported) > floor_of(importer):
                found.setdefault((importer, imported), []).append(f"{path.relative_to(PACKAGE.parent)}:{line}")
    return found


def test_every_package_has_a_floor() -> None:
    for path in PACKAGE.iterdir():
        if path.is_dir() and (path / "__init__.py").is_file():
            floor_of(f"spade.{path.name}")


def test_no_module_imports_a_higher_floor() -> None:
    found = upward_imports()
    new = {pair: where for pair, where in found.items() if pair not in KNOWN_UPWARD}
    assert not new, "imports that reach a higher floor (move the code down, or the import up):\n" + "\n".join(
        f"  {a} -> {b} at {', '.join(where)}" for (a, b), where in sorted(new.items()))
    fixed = KNOWN_UPWARD - set(found)
    assert not fixed, f"no longer imported upward, remove from KNOWN_UPWARD: {sorted(fixed)}"


def test_the_checker_sees_function_level_imports() -> None:
    source = PACKAGE / "metrics" / "baselines.py"
    names = [name for name, _ in spade_imports(source)]
    assert "spade.annotation.execution" in names  # imported inside a function there
    assert floor_of("spade.annotation.frame") > floor_of("spade.data.writer")
    assert floor_of("spade.train") == TOP and floor_of("spade") == TOP
