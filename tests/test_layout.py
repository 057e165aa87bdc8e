"""The house's rules (DESIGN.md section 2), read from the source: subpackages by stage with no import
cycles, small modules and classes, the solver takes only the mid-surface types from the plate's
mesh, and the memory guard lives in one module."""

import ast

import pytest

from conftest import REPO

PACKAGE = REPO / "textile_fenicsx"
# DESIGN.md 2: the stages' folders; at most this many modules directly in the package
STAGES = {"common", "model", "io", "plate", "correction", "pipeline", "volume", "homogenisation", "flow", "plot",
          "cli"}
TOP_MODULES = 12
MODULE_LINES = 500
CLASS_LINES = 200


def module_name(path) -> str:
    parts = path.relative_to(REPO).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imported_modules(path) -> set[str]:
    """Every module a file imports from, at its top, inside functions or under TYPE_CHECKING."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module:
            names.add(node.module)
        elif isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
    return names


def import_graph() -> dict[str, set[str]]:
    """module -> the package's modules it imports, wherever the import stands (`from pkg import
    name` counts as the module pkg.name where that is one, else as pkg)."""
    modules = {module_name(p): p for p in PACKAGE.rglob("*.py")}
    graph = {}
    for name, path in modules.items():
        targets = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module:
                for alias in node.names:
                    sub = f"{node.module}.{alias.name}"
                    targets.add(sub if sub in modules else node.module)
            elif isinstance(node, ast.Import):
                targets.update(alias.name for alias in node.names)
        graph[name] = {t for t in targets if t in modules and t != name}
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan)."""
    index, low, stack, on, found = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in graph:
        if v not in index:
            visit(v)
    return found


@pytest.mark.serial
def test_the_cycle_finder_finds_a_cycle_and_no_false_one():
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": {"c"}, "c": set()}) == []


@pytest.mark.serial
def test_no_import_cycles_between_modules():
    assert cycles(import_graph()) == []


@pytest.mark.serial
def test_the_package_is_folders_by_stage_with_few_modules_at_its_top():
    folders = {p.name for p in PACKAGE.iterdir() if p.is_dir() and (p / "__init__.py").is_file()}
    assert folders == STAGES
    top = sorted(p.name for p in PACKAGE.glob("*.py"))
    assert len(top) <= TOP_MODULES, top


@pytest.mark.serial
def test_no_module_over_500_lines_and_no_class_over_200():
    long_modules, long_classes = [], []
    for path in PACKAGE.rglob("*.py"):
        text = path.read_text()
        if len(text.splitlines()) > MODULE_LINES:
            long_modules.append((module_name(path), len(text.splitlines())))
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, ast.ClassDef) and node.end_lineno - node.lineno + 1 > CLASS_LINES:
                long_classes.append((module_name(path), node.name, node.end_lineno - node.lineno + 1))
    assert long_modules == [] and long_classes == []


@pytest.mark.serial
def test_the_solver_takes_only_the_mid_surface_types_from_the_plate_mesh():
    used = {module for path in (PACKAGE / "plate" / "solver").glob("*.py") for module in imported_modules(path)
            if module.startswith("textile_fenicsx.plate.mesh")}
    assert used == {"textile_fenicsx.plate.mesh.midsurface"}


@pytest.mark.serial
def test_the_memory_guard_lives_in_one_module():
    for marker in ("MemAvailable", "malloc_trim", "BYTES_PER_DOF ="):
        holders = [p.relative_to(REPO).as_posix() for p in PACKAGE.rglob("*.py") if marker in p.read_text()]
        assert holders == ["textile_fenicsx/common/memory.py"], (marker, holders)
