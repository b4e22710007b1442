"""Second-order (curved) geometry with a P1 displacement.

The contact nodes are the mesh's vertices, which lie on the curved surface; the nodal
normals and the lumped mass of the vertex rule are evaluated on the curved facets. The
solution must solve its discrete problem (against SNES VI), balance its forces, and stay
close to the same body meshed with straight facets.
"""

from __future__ import annotations

import numpy as np
import pytest
import ufl
from dolfinx import fem
from mpi4py import MPI

import admm_dolfinx
from admm_dolfinx.scenes.material import LinearElastic
from admm_dolfinx.studies.baselines import solve_snes_vi

gmsh = pytest.importorskip("gmsh")
from dolfinx.io import gmsh as gmshio  # noqa: E402

R, TOP, ARC = 1.0, 2, 3


def _half_disc(order: int):
    """A half disc of radius R, flat side up at y = R, resting on its arc above y = 0."""
    gmsh.initialize()
    gmsh.option.setNumber("General.Terminal", 0)
    if MPI.COMM_WORLD.rank == 0:
        disc = gmsh.model.occ.addDisk(0, R, 0, R, R)
        box = gmsh.model.occ.addRectangle(-R, R, 0, 2 * R, R)
        gmsh.model.occ.cut([(2, disc)], [(2, box)])
        gmsh.model.occ.synchronize()
        gmsh.model.addPhysicalGroup(2, [s[1] for s in gmsh.model.getEntities(2)], 1)
        for _, curve in gmsh.model.getEntities(1):
            y = gmsh.model.occ.getCenterOfMass(1, curve)[1]
            gmsh.model.addPhysicalGroup(1, [curve], TOP if abs(y - R) < 1e-8 else ARC)
        gmsh.option.setNumber("Mesh.CharacteristicLengthMax", 0.08)
        gmsh.model.mesh.generate(2)
        gmsh.model.mesh.setOrder(order)
    data = gmshio.model_to_mesh(gmsh.model, MPI.COMM_WORLD, 0, gdim=2)
    gmsh.finalize()
    msh, tags = data.mesh, data.facet_tags
    material = LinearElastic(E=1.0, nu=0.3)
    V = fem.functionspace(msh, ("Lagrange", 1, (2,)))
    u, v = ufl.TrialFunction(V), ufl.TestFunction(V)
    L = ufl.dot(fem.Constant(msh, (0.0, 0.0)), v) * ufl.dx
    top = fem.locate_dofs_topological(V, 1, tags.find(TOP))
    bc = fem.dirichletbc(np.array([0.0, -0.05]), top, V)
    floor = admm_dolfinx.Plane((0.0, 0.0), (0.0, 1.0))
    return admm_dolfinx.ContactProblem(material.bilinear_form(u, v), L, [bc], tags, ARC, floor)


def test_p1_displacement_on_curved_geometry():
    straight, curved = _half_disc(1), _half_disc(2)
    assert curved.mesh.geometry.cmaps[0].degree == 2
    results = []
    for problem in (straight, curved):
        result = admm_dolfinx.ADMMSolver(problem, rtol=1e-10).solve()
        reference = solve_snes_vi(problem)
        u, u_ref = result.u.x.petsc_vec, reference.u.x.petsc_vec
        assert (u - u_ref).norm() <= 1e-8 * u_ref.norm()
        force = result.contact_force
        assert np.linalg.norm(force + result.reaction_force(TOP)) <= 1e-8 * force[1]
        # the lowest node stays on the plane: nothing sinks below it
        assert MPI.COMM_WORLD.allreduce(result.gap().x.array.min(initial=0.0), MPI.MIN) > -1e-9
        results.append(result)
    # the same body: the curved facets change the answer by a small amount only
    f_straight, f_curved = results[0].contact_force[1], results[1].contact_force[1]
    assert f_curved == pytest.approx(f_straight, rel=2e-2)
    assert results[1].contact_area == pytest.approx(results[0].contact_area, rel=0.1)


def test_outputs_on_curved_geometry(tmp_path_factory):
    """XDMF (which stores functions in the geometry's degree) and VTX both write a P1
    solution on second-order geometry; the P2 copy XDMF writes is exact."""
    from admm_dolfinx.io.output import _in_geometry_degree, write_xdmf
    from admm_dolfinx.io.paraview import ContactWriter

    problem = _half_disc(2)
    result = admm_dolfinx.ADMMSolver(problem).solve()
    comm = MPI.COMM_WORLD
    folder = comm.bcast(str(tmp_path_factory.mktemp("curved")) if comm.rank == 0 else None)
    write_xdmf(f"{folder}/solution.xdmf", [result.u, result.pressure])
    with ContactWriter(problem, f"{folder}/contact.bp") as writer:
        writer.write(result, 0.0)
    comm.Barrier()
    text = open(f"{folder}/solution.xdmf").read()
    assert 'Name="displacement"' in text and f'Name="{result.pressure.name}"' in text
    quadratic = _in_geometry_degree(result.u, 2)
    assert quadratic.function_space.element.basix_element.degree == 2
    back = fem.Function(result.u.function_space)
    back.interpolate(quadratic)
    error = comm.allreduce(float(np.abs(back.x.array - result.u.x.array).max()), MPI.MAX)
    assert error <= 1e-14 * comm.allreduce(float(np.abs(result.u.x.array).max()), MPI.MAX)
