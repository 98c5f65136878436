"""The layers of ``shared/DESIGN.md``, enforced on the source: no upward import, no circle, no
controller importing a task module.

Read from the source files with :mod:`ast` (every ``import``, at module level or inside a
function), not by importing them. import-linter's graph builder walks each package's own
folder, and two of ours live in other folders (``baselines/`` installs as
``cir_gym.baselines``, ``agents/`` as ``cir_gym.agents``), so it would not see them.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: folder of the repository -> the package it installs as (pyproject's package-dir)
FOLDERS = {"cir_gym": "cir_gym", "baselines": "cir_gym.baselines", "agents": "cir_gym.agents"}

#: top to bottom; a module may import its own layer's modules and the layers below it
LAYERS: list[tuple[str, ...]] = [
    ("cir_gym.cli",),
    ("cir_gym.scoring",),
    ("cir_gym.agents",),
    ("cir_gym.baselines", "cir_gym.evaluation"),  # beside each other, independent
    ("cir_gym.envs", "cir_gym"),  # the package root registers the environments
    # the science: every other module of cir_gym
]
SCIENCE = len(LAYERS)


def modules() -> dict[str, Path]:
    """Every module of the installed packages, by its import name."""
    found = {}
    for folder, package in FOLDERS.items():
        for path in sorted((ROOT / folder).rglob("*.py")):
            parts = path.relative_to(ROOT / folder).with_suffix("").parts
            if parts[-1] == "__init__":
                parts = parts[:-1]
            found[".".join((package, *parts))] = path
    return found


MODULES = modules()


def _package(name: str, path: Path) -> str:
    return name if path.name == "__init__.py" else name.rpartition(".")[0]


def imports(name: str, path: Path) -> set[str]:
    """The project modules ``name`` imports (``from a import b`` is ``a.b`` when that is a
    module, else ``a``)."""
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                package = _package(name, path).split(".")
                base = ".".join(package[: len(package) - node.level + 1] + ([base] if base else []))
            targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in MODULES else base
                       for a in node.names]
        else:
            continue
        for target in targets:
            while target and target not in MODULES:  # a name inside a module
                target = target.rpartition(".")[0]
            if target and target != name:
                found.add(target)
    return found


GRAPH = {name: imports(name, path) for name, path in MODULES.items()}


def layer(name: str) -> int:
    for i, members in enumerate(LAYERS):
        for m in members:
            if name == m or (m != "cir_gym" and name.startswith(m + ".")):
                return i
    return SCIENCE


def test_the_tree_is_read() -> None:
    """The contracts below see every layer (a moved folder would make them vacuous)."""
    assert {layer(m) for m in MODULES} == set(range(SCIENCE + 1))
    assert "cir_gym.scoring.policies" in GRAPH["cir_gym.cli"]
    assert "cir_gym.baselines.base" in GRAPH["cir_gym.baselines.centralized"]


@pytest.mark.parametrize("name", sorted(MODULES))
def test_no_upward_import(name: str) -> None:
    upward = sorted(t for t in GRAPH[name] if layer(t) < layer(name))
    assert not upward, f"{name} (layer {layer(name)}) imports a layer above it: {upward}"


def test_the_baselines_and_the_evaluator_are_independent() -> None:
    for name, targets in GRAPH.items():
        for a, b in (("cir_gym.baselines", "cir_gym.evaluation"),
                     ("cir_gym.evaluation", "cir_gym.baselines")):
            if name == a or name.startswith(a + "."):
                assert not [t for t in targets if t == b or t.startswith(b + ".")], (name, b)


def test_no_controller_imports_a_task_module() -> None:
    """Task facts reach the controllers through ``TaskContext`` (cir_gym.context), never by
    importing an environment."""
    for name, targets in GRAPH.items():
        if name.startswith("cir_gym.baselines"):
            tasks = sorted(t for t in targets if t.startswith("cir_gym.envs"))
            assert not tasks, f"{name} imports {tasks}"


def test_nothing_imports_the_command_line() -> None:
    importers = sorted(n for n, targets in GRAPH.items() if "cir_gym.cli" in targets)
    assert not importers, f"the command line is a leaf; imported by {importers}"


def test_no_import_circle() -> None:
    """No strongly connected component of more than one module (Tarjan's algorithm). A
    package's ``__init__`` re-exporting its modules is not a circle with them, so an edge from
    a module to its own package's ``__init__`` is left out (``cir_gym`` itself included)."""

    def inside(child: str, package: str) -> bool:
        return child.startswith(package + ".") and MODULES[package].name == "__init__.py"

    edges = {n: {t for t in ts if not inside(n, t)} for n, ts in GRAPH.items()}
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    circles: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in edges[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                circles.append(sorted(component))

    for v in sorted(edges):
        if v not in index:
            visit(v)
    assert not circles, f"import circles: {circles}"
