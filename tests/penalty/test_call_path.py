"""The r* computation reads as a short pipeline: few modules, no call back up the chain.

Traced with ``sys.setprofile`` while ``ADMMSolver(problem)`` computes its penalty: every
call from one module of the package into another is an edge. The edges must form an
acyclic graph (no module is re-entered from a module it called, e.g. through a
callback), and the modules visited must be few.
"""

from __future__ import annotations

import sys

import pytest

import admm_dolfinx as ad
import admm_dolfinx.admm.solver as solver_module
from admm_dolfinx.scenes import example1, example3

pytestmark = pytest.mark.timeout(600)


def _trace(problem, function_name, **settings):
    """(modules visited, edges) while ``solver_module.<function_name>`` runs."""
    edges: list[tuple[str, str]] = []
    stack: list[str] = []
    original = getattr(solver_module, function_name)

    def profile(frame, event, arg):
        module = frame.f_globals.get("__name__", "")
        if event not in ("call", "return") or not module.startswith("admm_dolfinx"):
            return
        if event == "call":
            caller = stack[-1] if stack else "admm_dolfinx.admm.solver"
            if module != caller:
                edges.append((caller, module))
            stack.append(module)
        elif stack:
            stack.pop()

    def traced(*args, **kwargs):
        sys.setprofile(profile)
        try:
            return original(*args, **kwargs)
        finally:
            sys.setprofile(None)

    setattr(solver_module, function_name, traced)
    try:
        ad.ADMMSolver(problem, **settings).destroy()
    finally:
        setattr(solver_module, function_name, original)
    # the package's plumbing (_mpi: collective checks, _logging) is not a step of the
    # pipeline: it is left out of the count, not out of the cycle check
    modules = {"admm_dolfinx.admm.solver", *(b for _, b in edges)}
    modules = {m for m in modules if not m.rsplit(".", 1)[-1].startswith("_")}
    return modules, set(edges)


def _cycle(edges) -> list[str] | None:
    """A cycle of the directed graph, or None."""
    graph: dict[str, set[str]] = {}
    for a, b in edges:
        graph.setdefault(a, set()).add(b)
    state: dict[str, int] = {}

    def visit(node, path):
        state[node] = 1
        for nxt in graph.get(node, ()):
            if state.get(nxt) == 1:
                return [*path, node, nxt]
            if nxt not in state and (found := visit(nxt, [*path, node])):
                return found
        state[node] = 2
        return None

    for node in list(graph):
        if node not in state and (found := visit(node, [])):
            return found
    return None


@pytest.mark.parametrize(
    "scene, settings, most",
    [
        (lambda: example1(h=1 / 16), {}, 6),  # 2D default: dense r*
        # 3D default: multigrid, and layers of cells along Γ_C (problem/contact_layer.py)
        (lambda: example3(level=0), {}, 7),
        # the factorised method also enters the step-1 operator that it shares
        (lambda: example3(level=0), {"expert": {"penalty_method": "factorised"}}, 7),
    ],
    ids=["2d-dense", "3d-local", "3d-factorised"],
)
def test_penalty_call_path(scene, settings, most):
    modules, edges = _trace(scene().problem(), "estimate_penalty", **settings)
    assert _cycle(edges) is None, f"a module is re-entered: {_cycle(edges)}"
    assert len(modules) <= most, sorted(modules)


def test_surface_penalty_call_path():
    """The 3D default's r and β of the surface metric."""
    modules, edges = _trace(example3(level=0).problem(), "estimate_surface_penalty")
    assert _cycle(edges) is None, f"a module is re-entered: {_cycle(edges)}"
    assert len(modules) <= 6, sorted(modules)


def test_cycle_finder_finds_a_callback():
    """The check can fail: a callback from a helper back into its caller is a cycle."""
    assert _cycle({("a", "b"), ("b", "a")}) in (["a", "b", "a"], ["b", "a", "b"])
    assert _cycle({("a", "b"), ("b", "c"), ("a", "c")}) is None
