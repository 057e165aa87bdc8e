"""The house's rules (DESIGN.md section 2), read from the source: the solver takes only the
mid-surface types from meshes/, and the memory guard lives in one module."""

import ast

import pytest

from conftest import REPO

PACKAGE = REPO / "textile_fenicsx"


def imported_modules(path) -> set[str]:
    """Every module a file imports from, at its top or inside functions."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module:
            names.add(node.module)
        elif isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
    return names


@pytest.mark.serial
def test_the_solver_takes_only_the_mid_surface_types_from_meshes():
    used = {module for path in (PACKAGE / "solver").glob("*.py") for module in imported_modules(path)
            if module.startswith("textile_fenicsx.meshes")}
    assert used == {"textile_fenicsx.meshes.midsurface"}


@pytest.mark.serial
def test_the_memory_guard_lives_in_one_module():
    sources = [*PACKAGE.rglob("*.py"), *(REPO / "meshes").glob("*.py"), *(REPO / "forms").glob("*.py")]
    for marker in ("MemAvailable", "malloc_trim", "BYTES_PER_DOF ="):
        holders = [p.relative_to(REPO).as_posix() for p in sources if marker in p.read_text()]
        assert holders == ["textile_fenicsx/memory.py"], (marker, holders)
