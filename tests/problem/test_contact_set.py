"""Contact geometry: lumped mass, nodal normals, the UFL normal-mass form, exclusions."""

import numpy as np
import pytest
import ufl
from dolfinx import fem, mesh
from dolfinx.fem import petsc as fem_petsc
from mpi4py import MPI
from petsc4py import PETSc

from admm_dolfinx import ContactProblem, Plane
from admm_dolfinx.scenes.library import example1
from admm_dolfinx.scenes.material import LinearElastic
from admm_dolfinx.scenes.meshing import tag_boundary


def box_problem(dim: int, n: int, clamp_top: bool = True):
    """Unit square/cube, Γ_C = bottom, clamped top, plane at distance 0.01 below."""
    comm = MPI.COMM_WORLD
    if dim == 2:
        msh = mesh.create_unit_square(comm, n, n)
    else:
        msh = mesh.create_unit_cube(comm, n, n, n)
    top = 2
    rules = {
        1: lambda x: np.isclose(x[dim - 1], 0.0),
        top: lambda x: np.isclose(x[dim - 1], 1.0),
    }
    ft = tag_boundary(msh, rules)
    V = fem.functionspace(msh, ("Lagrange", 1, (dim,)))
    u, v = ufl.TrialFunction(V), ufl.TestFunction(V)
    mat = LinearElastic(1.0, 0.3)
    f = fem.Constant(msh, np.array([0.0] * (dim - 1) + [-1.0]))
    bcs = []
    if clamp_top:
        dofs = fem.locate_dofs_topological(V, dim - 1, ft.find(top))
        bcs = [fem.dirichletbc(np.zeros(dim), dofs, V)]
    point = np.zeros(dim)
    point[-1] = -0.01
    normal = np.zeros(dim)
    normal[-1] = 1.0
    return ContactProblem(
        mat.bilinear_form(u, v), ufl.dot(f, v) * ufl.dx, bcs, ft, 1, Plane(point, normal)
    )


@pytest.mark.parametrize("dim,n", [(2, 7), (3, 4)])
def test_flat_contact_mass_and_normals(dim, n):
    problem = box_problem(dim, n)
    c = problem.contact
    comm = problem.comm
    assert problem.num_contact_nodes == (n + 1) ** (dim - 1)
    total = comm.allreduce(c.mass.sum(), op=MPI.SUM)
    assert total == pytest.approx(1.0, rel=1e-13)  # |Γ_C| = 1
    expected = np.zeros(dim)
    expected[-1] = -1.0
    np.testing.assert_allclose(c.normals, np.tile(expected, (c.normals.shape[0], 1)), atol=1e-14)
    np.testing.assert_allclose(c.gap, 0.01, rtol=1e-12)


@pytest.mark.parametrize("dim,n", [(2, 6), (3, 3)])
def test_lumped_mass_is_row_sum_of_consistent_mass(dim, n):
    """Vertex rule ∫φ_j ds equals the row sum of the exactly integrated boundary mass."""
    problem = box_problem(dim, n)
    Q = problem.contact.Q
    q, w = ufl.TrialFunction(Q), ufl.TestFunction(Q)
    ds = ufl.Measure("ds", domain=problem.mesh, subdomain_data=problem.facet_tags)
    Mc = fem_petsc.assemble_matrix(fem.form(q * w * ds(1)))
    Mc.assemble()
    ones, rowsum = Mc.createVecs()
    ones.set(1.0)
    Mc.mult(ones, rowsum)
    np.testing.assert_allclose(
        rowsum.array_r[problem.contact.dofs], problem.contact.mass, rtol=1e-12
    )
    for obj in (Mc, ones, rowsum):
        obj.destroy()


@pytest.mark.parametrize("scene_h", [1 / 8, 1 / 16])
def test_normal_mass_form_equals_NtMN(scene_h):
    """The UFL vertex-rule form r·(u·n_h, v·n_h)_Γc equals the node-local NᵀMN (free dofs)."""
    problem = example1(h=scene_h).problem()
    x, y, z = problem.create_vector(), problem.create_vector(), problem.create_vector()
    rng = np.random.default_rng(3 + problem.comm.rank)
    with x as arr:
        arr[:] = rng.standard_normal(arr.size)
    fem_petsc.set_bc(x, problem.bcs, alpha=0.0)  # K acts on free dofs only
    problem.K.mult(x, y)
    z.set(0.0)
    problem.add_normal_force(z, problem.apply_normal(x))
    assert y.norm() > 0
    z.axpy(-1.0, y)
    assert z.norm() <= 1e-13 * y.norm()
    for v in (x, y, z):
        v.destroy()


def test_dirichlet_corner_node_is_excluded():
    problem = example1(h=1 / 8, mesher="builtin").problem()
    # Γ_C has 17 nodes; the one at the clamped corner (0, 0) cannot move: 16 remain.
    assert problem.num_contact_nodes == 16
    assert problem.contact.num_excluded == 1
    coords = np.concatenate(problem.comm.allgather(problem.contact.coordinates))
    assert not np.any(np.all(np.isclose(coords, [0.0, 0.0]), axis=1))


def test_apply_normal_reads_nodal_normal_component():
    problem = box_problem(3, 3, clamp_top=True)
    u = fem.Function(problem.V)
    u.interpolate(lambda x: np.vstack([x[0], 2 * x[1], 3.0 + x[0] * x[1]]))
    nu = problem.apply_normal(u.x.petsc_vec)
    xc = problem.contact.coordinates
    np.testing.assert_allclose(nu, -(3.0 + xc[:, 0] * xc[:, 1]), rtol=1e-13)
    assert PETSc.COMM_WORLD.getSize() == MPI.COMM_WORLD.size
