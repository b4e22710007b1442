"""The outputs an engineer reaches for: force, reaction, area, active set, gap, ParaView.

Each is checked against an independent answer: the contact force against the support
reactions (equilibrium of the discrete system, to round-off), the solution against
SNES VI on the same discrete problem, P1 against Q1 cells, 2D and 3D, a contact marker
split into two tags against one tag, the contact area of a fully pressed face against
its measure. Serially and under MPI (the test suite's -n 2, 3 runs).
"""

from __future__ import annotations

import numpy as np
import pytest
import ufl
from dolfinx import fem, mesh
from mpi4py import MPI

import admm_dolfinx
from admm_dolfinx.io.paraview import ContactWriter
from admm_dolfinx.scenes.material import LinearElastic
from admm_dolfinx.studies.baselines import solve_snes_vi

MATERIAL = LinearElastic(E=100.0, nu=0.3)
BOTTOM, TOP, BOTTOM_RIGHT = 1, 2, 3


def _block(dim: int, cell: str, n: int, *, split_bottom: bool = False):
    """A unit block (or square) whose top is pushed down by 0.03 onto a plane 0.01 below.

    The plane is tilted slightly, so the contact zone is a part of the bottom face. With
    ``split_bottom`` the bottom carries two tags (left and right halves).
    """
    comm = MPI.COMM_WORLD
    if dim == 2:
        kind = mesh.CellType.triangle if cell == "P1" else mesh.CellType.quadrilateral
        msh = mesh.create_unit_square(comm, n, n, kind)
    else:
        kind = mesh.CellType.tetrahedron if cell == "P1" else mesh.CellType.hexahedron
        msh = mesh.create_unit_cube(comm, n, n, n, kind)
    fdim = dim - 1
    top = mesh.locate_entities_boundary(msh, fdim, lambda x: np.isclose(x[dim - 1], 1.0))
    bottom = mesh.locate_entities_boundary(msh, fdim, lambda x: np.isclose(x[dim - 1], 0.0))
    right = mesh.compute_midpoints(msh, fdim, bottom)[:, 0] > 0.5
    bottom_values = np.where(right & split_bottom, BOTTOM_RIGHT, BOTTOM)
    facets = np.concatenate([bottom, top])
    values = np.concatenate([bottom_values, np.full(top.size, TOP)]).astype(np.int32)
    order = np.argsort(facets)
    tags = mesh.meshtags(msh, fdim, facets[order], values[order])
    V = fem.functionspace(msh, ("Lagrange", 1, (dim,)))
    u, v = ufl.TrialFunction(V), ufl.TestFunction(V)
    a = MATERIAL.bilinear_form(u, v)
    L = ufl.dot(fem.Constant(msh, np.zeros(dim)), v) * ufl.dx
    pressed = np.zeros(dim)
    pressed[-1] = -0.03
    bc = fem.dirichletbc(pressed, fem.locate_dofs_topological(V, fdim, tags.find(TOP)), V)
    normal = np.zeros(dim)
    normal[-1], normal[0] = 1.0, 0.05
    floor = admm_dolfinx.Plane(point=np.eye(dim)[-1] * -0.01, normal=normal)
    marker = (BOTTOM, BOTTOM_RIGHT) if split_bottom else BOTTOM
    return admm_dolfinx.ContactProblem(a, L, [bc], tags, marker, floor)


CASES = [(2, "P1", 16), (2, "Q1", 16), (3, "P1", 6), (3, "Q1", 6)]


@pytest.mark.parametrize(("dim", "cell", "n"), CASES)
def test_contact_force_balances_the_support_reaction(dim, cell, n):
    problem = _block(dim, cell, n)
    # the balance holds at the discrete equilibrium, i.e. to the solve's tolerance
    solver = admm_dolfinx.ADMMSolver(problem, petsc_options_prefix=f"force{dim}{cell}_", rtol=1e-11)
    result = solver.solve()
    assert result.converged and 0 < result.num_active < result.num_contact_nodes
    force = result.contact_force
    reaction = result.reaction_force(TOP)
    assert force[-1] > 0.0  # the obstacle pushes the body up
    # no load: the obstacle's force and the supports' balance to round-off
    assert np.linalg.norm(force + reaction) <= 1e-8 * np.linalg.norm(force)
    # the same on every rank
    assert np.allclose(MPI.COMM_WORLD.allgather(force), force, rtol=0, atol=0)
    solver.destroy()


@pytest.mark.parametrize(("dim", "cell", "n"), CASES)
def test_outputs_agree_with_snes_vi_and_each_other(dim, cell, n):
    problem = _block(dim, cell, n)
    # the plane is tilted: SNES VI's bounds need axis-aligned directions, so compare
    # on the same block against a level plane
    level = admm_dolfinx.Plane(point=np.eye(dim)[-1] * -0.01, normal=np.eye(dim)[-1])
    problem.update_obstacle(level)
    solver = admm_dolfinx.ADMMSolver(problem, petsc_options_prefix=f"snes{dim}{cell}_", rtol=1e-9)
    result = solver.solve()
    reference = solve_snes_vi(problem)
    u, u_ref = result.u.x.petsc_vec, reference.u.x.petsc_vec
    assert (u - u_ref).norm() <= 1e-6 * u_ref.norm()
    # a level plane: the force is vertical, and is mean pressure × contact area
    force = result.contact_force
    assert abs(force[0]) <= 1e-8 * force[-1]
    assert result.mean_pressure * result.contact_area == pytest.approx(force[-1], rel=1e-12)
    # the gap function: g − N u, non-negative up to the tolerance, zero where in contact
    gap = result.gap().x.array
    active = result.active_marker().x.array
    scale = 0.01
    assert gap.min() >= -1e-6 * scale
    assert np.all(np.abs(gap[active > 0.5]) <= 1e-6 * scale)
    # the active facets: every vertex active; as many as the marker function implies
    tags = result.active_facets(value=7)
    assert tags.dim == dim - 1 and np.all(tags.values == 7)
    owned = tags.indices[tags.indices < problem.mesh.topology.index_map(dim - 1).size_local]
    count = MPI.COMM_WORLD.allreduce(owned.size, op=MPI.SUM)
    assert 0 < count
    measure = fem.assemble_scalar(
        fem.form(
            fem.Constant(problem.mesh, 1.0)
            * ufl.ds(domain=problem.mesh, subdomain_data=tags, subdomain_id=7)
        )
    )
    area = MPI.COMM_WORLD.allreduce(measure, op=MPI.SUM)
    # the facets in contact lie inside the lumped contact zone and are most of it
    assert 0.5 * result.contact_area < area <= result.contact_area + 1e-12
    solver.destroy()


@pytest.mark.parametrize(("dim", "cell", "n"), [(2, "P1", 16), (3, "Q1", 5)])
def test_a_tuple_of_contact_tags_is_the_union_of_their_facets(dim, cell, n):
    one = _block(dim, cell, n)
    two = _block(dim, cell, n, split_bottom=True)
    assert two.contact_marker == (BOTTOM, BOTTOM_RIGHT)
    assert two.num_contact_nodes == one.num_contact_nodes
    r1 = admm_dolfinx.ADMMSolver(one, petsc_options_prefix="tag1_").solve()
    r2 = admm_dolfinx.ADMMSolver(two, petsc_options_prefix="tag2_").solve()
    assert r1.iterations == r2.iterations
    diff = r1.u.x.petsc_vec.copy()
    diff.axpy(-1.0, r2.u.x.petsc_vec)
    assert diff.norm() <= 1e-12 * r1.u.x.petsc_vec.norm()
    assert r1.contact_area == pytest.approx(r2.contact_area, rel=1e-13)


def test_contact_area_of_a_fully_pressed_face_is_its_measure():
    problem = _block(2, "Q1", 12)
    problem.update_obstacle(admm_dolfinx.Plane(point=(0.0, 0.0), normal=(0.0, 1.0)))
    result = admm_dolfinx.ADMMSolver(problem, petsc_options_prefix="full_").solve()
    assert result.num_active == result.num_contact_nodes
    # every node of the bottom except none is a contact node: the whole unit length
    assert result.contact_area == pytest.approx(1.0, rel=1e-12)
    marker_max = MPI.COMM_WORLD.allreduce(result.active_marker().x.array.max(initial=0), MPI.MAX)
    assert marker_max == 1.0


def test_bad_contact_marker_is_a_clear_error():
    from admm_dolfinx.problem.contact_set import as_marker

    with pytest.raises(TypeError, match="facet tag"):
        as_marker((1.5,))
    with pytest.raises(TypeError, match="facet tag"):
        as_marker(True)
    with pytest.raises(TypeError, match="empty"):
        as_marker(())
    assert as_marker([3, 3]) == 3 and as_marker((1, 2)) == (1, 2)


@pytest.mark.parametrize(("dim", "cell", "n"), [(2, "P1", 8), (3, "Q1", 4)])
def test_paraview_writer_writes_every_load_step(dim, cell, n, tmp_path_factory):
    comm = MPI.COMM_WORLD
    folder = tmp_path_factory.mktemp("vtx") if comm.rank == 0 else None
    folder = comm.bcast(folder, root=0)
    problem = _block(dim, cell, n)
    solver = admm_dolfinx.ADMMSolver(problem, petsc_options_prefix=f"vtx{dim}_")
    path = folder / "contact.bp"
    with ContactWriter(problem, path, MATERIAL.von_mises) as writer:
        result = solver.solve()
        writer.write(result, t=0.0)
        problem.update_obstacle(admm_dolfinx.Plane(np.eye(dim)[-1] * -0.005, np.eye(dim)[-1]))
        result = solver.solve(warm_start=result)
        writer.write(result, t=1.0)
        vm = writer.von_mises.x.array
        assert comm.allreduce(vm.max(initial=0.0), MPI.MAX) > 0.0
        assert np.all(np.isfinite(vm))
        # the written fields are the result's
        assert np.array_equal(writer.pressure.x.array, result.pressure.x.array)
    comm.barrier()
    if comm.rank == 0:
        assert path.is_dir() and (path / "md.idx").stat().st_size > 0
        assert sum(f.stat().st_size for f in path.iterdir()) > 1000
    with pytest.raises(ValueError, match=r"\.bp"):
        ContactWriter(problem, folder / "contact.xdmf")
    solver.destroy()
