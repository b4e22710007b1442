"""The package's imports run one way: down the floors of scene → problem → … → output.

Every ``admm_dolfinx`` import in the source, at module level or inside a function,
is read from the syntax tree and must go to a lower floor (or stay in its own
package). A new upward import, the kind that ties two packages into a cycle, fails
here with the file and the line.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

SOURCE = Path(__file__).resolve().parents[1] / "src" / "admm_dolfinx"

#: package (or top-level module) → floor; a package imports only lower floors.
FLOORS = {
    # the one home of MPI, logging, threads and the optional dependencies
    "_bootstrap": 0,
    "_extras": 0,
    "_logging": 0,
    "_mpi": 0,
    "_threads": 0,
    # linear algebra that knows nothing of contact
    "linalg": 1,
    # the discrete problem, from the user's forms, conditions and obstacle
    "problem": 2,
    # scenes build problems; the operators of a problem (A + rK, condensed, surface metric)
    "scenes": 3,
    "operators": 3,
    "penalty": 4,
    "admm": 5,
    "adapt": 6,
    "io": 6,
    "studies": 7,
    "cli": 8,
    "__init__": 8,
    "__main__": 8,
}


def _package(path: Path) -> str:
    """The package (first folder under admm_dolfinx) or top-level module of a file."""
    parts = path.relative_to(SOURCE).with_suffix("").parts
    return parts[0]


def _imports(path: Path, root: Path = SOURCE) -> list[tuple[str, int]]:
    """The admm_dolfinx modules a file of the package at ``root`` imports, with lines."""
    module = ["admm_dolfinx", *path.relative_to(root).with_suffix("").parts]
    if module[-1] == "__init__":
        module.pop()
        module.append("__init__")  # relative imports count from the package itself
    found = []
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = module[: -node.level]
                name = ".".join([*base, node.module] if node.module else base)
            else:
                name = node.module or ""
            found.append((name, node.lineno))
        elif isinstance(node, ast.Import):
            found.extend((alias.name, node.lineno) for alias in node.names)
    return [(name, line) for name, line in found if name.startswith("admm_dolfinx.")]


def _sources() -> list[Path]:
    return sorted(SOURCE.rglob("*.py"))


def test_every_package_has_a_floor():
    """A new package must say where it sits (else the check below would skip it)."""
    packages = {_package(path) for path in _sources()}
    assert packages <= set(FLOORS), f"packages without a floor: {sorted(packages - set(FLOORS))}"


def test_no_import_runs_up_a_floor():
    """Every import goes to its own package or a lower floor."""
    upward = []
    for path in _sources():
        here = _package(path)
        for name, line in _imports(path):
            there = name.split(".")[1]
            if there == here or there not in FLOORS:
                continue
            same_infrastructure = FLOORS[here] == FLOORS[there] == 0
            if FLOORS[there] >= FLOORS[here] and not same_infrastructure:
                upward.append(f"{path.relative_to(SOURCE)}:{line} ({here}) imports {name}")
    assert not upward, "imports that run up or across a floor:\n" + "\n".join(upward)


@pytest.mark.parametrize(
    ("source", "expected"),
    [
        ("from admm_dolfinx.admm.solver import ADMMSolver\n", "admm_dolfinx.admm.solver"),
        ("def f():\n    from admm_dolfinx.io import plotting\n", "admm_dolfinx.io"),
        ("from ..admm import solver\n", "admm_dolfinx.admm"),
    ],
)
def test_the_reader_sees_every_form_of_import(tmp_path, source, expected):
    """Module-level, function-level and relative imports are all read."""
    package = tmp_path / "admm_dolfinx" / "problem"
    package.mkdir(parents=True)
    path = package / "example.py"
    path.write_text(source)
    assert [name for name, _ in _imports(path, tmp_path / "admm_dolfinx")] == [expected]
