"""The house rule, checked: an import only points down the layers, and no module imports itself back.

Layers, lowest first (ARCHITECTURE.md draws them). A module may import from its own layer's
package and from any lower layer; the algorithm packages (one layer) never import each other.
Imports are read from the source with ``ast`` — top-level and inside functions alike, since a
lazy import is still a dependency.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src" / "skincap"

#: Lowest first. Each entry: the packages/modules of one layer (dotted, below ``skincap``).
LAYERS: list[tuple[str, ...]] = [
    ("types", "errors", "_arrays", "backends", ""),  # "" = skincap/__init__.py
    ("data",),
    ("geometry",),
    ("io",),
    ("cleanup", "tracking", "deform", "solve"),  # the algorithms, independent of each other
    ("synth",),
    ("viz",),
    ("evaluate",),
    ("workflows",),
    ("batch",),
    ("cli",),
]


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(SRC.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _imports(path: Path, module: str) -> set[str]:
    """Every ``skincap`` module ``path`` imports (relative imports resolved)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names if a.name.split(".")[0] == "skincap")
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if target.split(".")[0] != "skincap":
                continue
            for alias in node.names:  # ``from skincap.io import gltf`` imports a module
                candidate = f"{target}.{alias.name}"
                is_module = (SRC.parent / candidate.replace(".", "/")).with_suffix(
                    ".py"
                ).is_file() or (SRC.parent / candidate.replace(".", "/")).is_dir()
                found.add(candidate if is_module else target)
    return found


def _graph() -> dict[str, set[str]]:
    return {_module_name(p): _imports(p, _module_name(p)) for p in sorted(SRC.rglob("*.py"))}


def _top(module: str) -> str:
    """The layer entry a module belongs to: ``skincap.io.c3d`` -> ``io``; ``skincap`` -> ``""``."""
    parts = module.split(".")
    top = parts[1] if len(parts) > 1 else ""
    return "cli" if top == "__main__" else top  # ``python -m skincap`` is the CLI


def _layer(module: str) -> int:
    top = _top(module)
    for index, members in enumerate(LAYERS):
        if top in members:
            return index
    raise AssertionError(
        f"{module}: its package {top!r} is in no layer; add it to LAYERS and ARCHITECTURE.md"
    )


def test_every_module_has_a_layer() -> None:
    for module in _graph():
        _layer(module)


def test_imports_point_down_the_layers() -> None:
    upward = []
    for module, targets in _graph().items():
        for target in sorted(targets):
            mine, theirs = _layer(module), _layer(target)
            if theirs > mine:
                upward.append(f"{module} -> {target} (layer {mine} -> {theirs})")
            elif theirs == mine and _top(module) != _top(target) and _top(target) not in LAYERS[0]:
                upward.append(f"{module} -> {target} (two packages of one layer)")
    assert not upward, "imports that point up or sideways:\n" + "\n".join(upward)


def test_no_import_cycle() -> None:
    graph = _graph()
    # A parent package's __init__ importing its own submodules is how a package exposes
    # them, not a cycle; every other edge counts.
    state: dict[str, int] = {}
    stack: list[str] = []
    cycles: list[str] = []

    def visit(node: str) -> None:
        state[node] = 1
        stack.append(node)
        for target in sorted(graph.get(node, ())):
            if target not in graph or target == node:
                continue
            if state.get(target) == 1:
                cycles.append(" -> ".join(stack[stack.index(target) :] + [target]))
            elif state.get(target) is None:
                visit(target)
        stack.pop()
        state[node] = 2

    for node in sorted(graph):
        if node not in state:
            visit(node)
    assert not cycles, "import cycles:\n" + "\n".join(cycles)


@pytest.mark.parametrize("path", ["tracking", "cleanup", "deform", "geometry", "io"])
def test_algorithm_and_format_packages_never_print(path: str) -> None:
    """Only the CLI prints: a library module calling print() would write into a user's pipe."""
    offenders = []
    for file in sorted((SRC / path).rglob("*.py")):
        for node in ast.walk(ast.parse(file.read_text(encoding="utf-8"))):
            if (
                isinstance(node, ast.Call)
                and isinstance(node.func, ast.Name)
                and node.func.id == "print"
            ):
                offenders.append(f"{file.relative_to(SRC)}:{node.lineno}")
    assert not offenders, offenders
