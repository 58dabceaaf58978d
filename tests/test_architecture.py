"""The package's shape: layers that import only downwards, no import cycles, Hydra only in the CLI."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "spidermatch"

LAYERS = (
    ("values", "shutdown", "memory", "defaults", "versions"),
    ("geometry",),
    ("data",),
    ("model",),
    ("eval",),
    ("solve",),
    ("dense",),
    ("validate",),
    ("model_size", "feature_transfer"),
    ("pipeline",),
    ("overlap_solve",),  # partial=both's overlap by a matching: a pipeline solve with a void vertex
    ("report",),  # pictures of results: below the API, whose Matching.save_pictures draws them
    ("api",),
    ("cli",),
)
"""Top-level parts of ``spidermatch``, bottom up: a part imports only from its own layer and those below."""

RANK = {part: rank for rank, parts in enumerate(LAYERS) for part in parts}


def module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imported_modules(path: Path) -> set[str]:
    """Every ``spidermatch`` module ``path`` imports, at the top or inside a function."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.add(node.module)
            found.update(f"{node.module}.{alias.name}" for alias in node.names)
    return {name for name in found if name.startswith("spidermatch.")}


def import_graph() -> dict[str, set[str]]:
    modules = {module_name(path): path for path in PACKAGE.rglob("*.py")}
    return {
        name: {target for target in imported_modules(path) if target in modules and target != name}
        for name, path in modules.items()
    }


def part(module: str) -> str:
    """The top-level part of ``spidermatch`` holding a module: ``spidermatch.solve.highs`` -> ``solve``."""
    return module.split(".")[1] if module.count(".") else ""


def test_every_part_has_a_layer():
    unplaced = sorted({part(name) for name in import_graph()} - set(RANK) - {""})
    assert unplaced == []


def test_imports_go_down_the_layers_only():
    upward = [
        f"{module} imports {target}"
        for module, targets in import_graph().items()
        for target in targets
        if part(module) and RANK[part(target)] > RANK[part(module)]
    ]
    assert upward == []


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        stack.append(node)
        for target in sorted(graph[node]):
            if state.get(target) == 1:
                return stack[stack.index(target) :] + [target]
            if target not in state and (cycle := visit(target)):
                return cycle
        stack.pop()
        state[node] = 2
        return None

    for node in sorted(graph):
        if node not in state and (cycle := visit(node)):
            return cycle
    return None


def test_no_import_cycles():
    graph = {name: {t for t in targets if t != "spidermatch"} for name, targets in import_graph().items()}
    assert find_cycle(graph) is None


def test_find_cycle_sees_a_lazy_cycle():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": set()}) is None


@pytest.mark.parametrize("framework", ["hydra", "omegaconf", "torch"])
def test_frameworks_stay_out_of_the_library(framework):
    users = []
    for path in PACKAGE.rglob("*.py"):
        if framework != "torch" and part(module_name(path)) == "cli":
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            names = []
            if isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module:
                names = [node.module]
            if any(name.split(".")[0] == framework for name in names):
                users.append(module_name(path))
    assert sorted(set(users)) == []
