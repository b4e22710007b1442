"""The mesh's bracket of a factorisation's cost, which spares the plan MUMPS's analysis
where the answer is obvious: the body's volume, the model's growth against the theory
of nested dissection, MUMPS's own count inside the bracket, and the same bracket on
every partition."""

from __future__ import annotations

import numpy as np
import pytest
import ufl
from dolfinx import fem, mesh
from dolfinx.fem import petsc as fem_petsc
from mpi4py import MPI

from admm_dolfinx.linalg.factor_estimate import mumps_estimate
from admm_dolfinx.linalg.factor_prediction import (
    FLOPS_CONSTANT,
    mesh_volume,
    nested_dissection,
    predict_factorisation,
)
from admm_dolfinx.problem.contact_set import mesh_bounds
from admm_dolfinx.scenes import example3, hertz_sphere

pytestmark = pytest.mark.timeout(300)
COMM = MPI.COMM_WORLD


def _box(sides, cells, cell_type="tetrahedron") -> mesh.Mesh:
    corners = [np.zeros(3), np.asarray(sides, dtype=float)]
    return mesh.create_box(COMM, corners, list(cells), getattr(mesh.CellType, cell_type))


def _elasticity(msh: mesh.Mesh, degree: int = 1):
    V = fem.functionspace(msh, ("Lagrange", degree, (3,)))
    u, v = ufl.TrialFunction(V), ufl.TestFunction(V)
    eps = ufl.sym(ufl.grad(u))
    A = fem_petsc.assemble_matrix(
        fem.form(ufl.inner(2 * eps + ufl.tr(eps) * ufl.Identity(3), ufl.grad(v)) * ufl.dx)
    )
    A.assemble()
    return A


@pytest.mark.parametrize("cell_type", ["tetrahedron", "hexahedron"])
def test_the_volume_is_the_cells_on_every_partition(cell_type):
    """A box of volume 3 measures 3 (each owned cell once, whatever the partition), and
    so does a sheared one (a hexahedron by its Jacobian at the centre); the Hertz
    sphere's quarter-ball (gmsh's tetrahedra) measures its inscribed polyhedron's
    volume, below the quarter-ball's π/6 R³ by the facets' chord error."""
    msh = _box((2.0, 3.0, 0.5), (4, 6, 2), cell_type)
    assert mesh_volume(msh) == pytest.approx(3.0, rel=1e-12)
    x = msh.geometry.x
    x[:, 0] += 0.3 * x[:, 2] + 0.1 * x[:, 1] ** 2  # a shear and a bend: volume kept
    assert mesh_volume(msh) == pytest.approx(3.0, rel=1e-12)
    sphere = hertz_sphere(level=0)
    quarter_ball = np.pi / 6.0 * 8.0**3
    assert 0.97 * quarter_ball < mesh_volume(sphere.mesh) <= quarter_ball


def test_the_model_grows_as_nested_dissection_does():
    """George's nested dissection on a grid of n unknowns: n² operations and n^{4/3}
    entries in a cube, n^{3/2} and n log n in a plate of fixed thickness, n and n in a
    bar of fixed section. The model's sums, at eight times the dofs (each side doubled;
    only the plate's two long sides, or the bar's length, at the same density), grow
    by those powers (n log n: a little over 1)."""
    density = 1e5
    shapes = [((1, 1, 1), 2.0, 4 / 3), ((1, 1, 0.05), 1.5, 1.1), ((0.05, 0.05, 1), 1.0, 1.0)]
    for sides, operations, entries in shapes:
        sides = np.asarray(sides, dtype=float)
        longest = sides == sides.max()
        longer = np.where(longest, 8.0 ** (1 / np.sum(longest)), 1)
        small = nested_dissection(sides, density * np.prod(sides))
        large = nested_dissection(sides * longer, density * np.prod(sides) * 8)
        growth = np.log(np.divide(large, small)) / np.log(8.0)
        assert growth == pytest.approx([operations, entries], abs=0.08)
    assert nested_dissection((1, 1, 1), 0.5) == (0.0, 0.0)
    with pytest.raises(ValueError, match="three positive sides"):
        nested_dissection((-1, -1, 1), 1e3)


def test_no_bracket_where_the_model_has_nothing_to_say():
    """A flat box, a box with a side that is not finite, or no dofs: no bracket (the
    plan then asks MUMPS's analysis), never a bracket of zero cost."""
    assert predict_factorisation((1.0, 1.0, 0.0), None, 1000) is None
    assert predict_factorisation((1.0, np.inf, 1.0), None, 1000) is None
    assert predict_factorisation((1.0, 1.0, 1.0), 1.0, 0) is None
    assert predict_factorisation((1.0, 1.0, 1.0), None, 1000) is not None


CASES = {
    "cube": lambda: (_box((1, 1, 1), (10, 10, 10)), 1),
    "bar": lambda: (_box((1, 1, 15), (4, 4, 60)), 1),
    "plate": lambda: (_box((20, 20, 1), (40, 40, 2)), 1),
    "degree 2": lambda: (_box((1, 1, 1), (6, 6, 6)), 2),
    "hexahedra": lambda: (_box((1, 1, 1), (10, 10, 10), "hexahedron"), 1),
}


@pytest.mark.parametrize("case", [*CASES, "example 3", "hertz sphere"])
def test_mumps_count_lies_in_the_bracket(case):
    """MUMPS's analysis (the parallel one under MPI) counts within the bracket, flops and
    memory, on small meshes of several shapes and elements
    (``python benchmarks/factor_prediction.py`` measures larger ones)."""
    if case in CASES:
        msh, degree = CASES[case]()
        A = _elasticity(msh, degree)
    else:
        scene = example3(level=1) if case == "example 3" else hertz_sphere(level=1)
        problem = scene.problem()
        msh, A = problem.mesh, problem.A
    sides = np.diff(mesh_bounds(msh), axis=0)[0]
    n = A.getSize()[0]
    bracket = predict_factorisation(sides, mesh_volume(msh), n, processes=COMM.size)
    estimate = mumps_estimate(A)
    assert bracket is not None and estimate is not None
    assert bracket.flops[0] <= estimate.flops <= bracket.flops[1]
    assert bracket.memory[0] <= estimate.memory <= bracket.memory[1]


def test_the_bracket_does_not_depend_on_the_partition():
    """On a box the model's count is that of the exact box (the volume summed over the
    ranks' owned cells, ghosts not counted twice; the bounds over all ranks), so serial
    and parallel runs agree, and every rank has the same bracket."""
    msh = _box((1.0, 2.0, 0.5), (5, 10, 3))
    n = 3 * msh.topology.index_map(0).size_global
    bracket = predict_factorisation(np.diff(mesh_bounds(msh), axis=0)[0], mesh_volume(msh), n)
    operations, _ = nested_dissection(np.array([1.0, 2.0, 0.5]), float(n))
    assert bracket is not None
    assert bracket.model_flops == pytest.approx(FLOPS_CONSTANT * operations, rel=1e-10)
    assert COMM.allreduce(bracket.model_flops, op=MPI.MAX) == bracket.model_flops
    assert COMM.allreduce(bracket.model_flops, op=MPI.MIN) == bracket.model_flops
