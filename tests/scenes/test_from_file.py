"""The user's own mesh file: ``scene_from_file`` and ``admm-dolfinx run --mesh``.

A 2D block written by gmsh (bottom tag 31, right 22, top 13, left 24), pressed onto a
rigid floor by a prescribed displacement of its top. Checked against the same problem
built from the file by DOLFINx's reader and UFL forms written here, against the
balance of forces, and against the bounds of elasticity for a block compressed
between a clamped top and a frictionless floor.
"""

import json

import numpy as np
import pytest
import ufl
from dolfinx import fem
from dolfinx.io import gmsh as gmshio
from mpi4py import MPI

import admm_dolfinx as ad
from admm_dolfinx.cli import main
from admm_dolfinx.scenes.from_file import scene_from_file

pytest.importorskip("gmsh")

E, NU, HEIGHT, PUSH, GAP = 1000.0, 0.3, 0.5, 0.01, 0.001


def _write_block(path):
    import gmsh

    gmsh.initialize(interruptible=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("block")
        face = gmsh.model.occ.addRectangle(0, 0, 0, 1.0, HEIGHT)
        gmsh.model.occ.synchronize()
        for dim, tag in gmsh.model.getBoundary([(2, face)], oriented=False):
            _, y, _ = gmsh.model.occ.getCenterOfMass(dim, tag)
            side = 3 if abs(y) < 1e-9 else (1 if abs(y - HEIGHT) < 1e-9 else 2)
            gmsh.model.addPhysicalGroup(1, [tag], side * 10 + tag)
        gmsh.model.addPhysicalGroup(2, [face], 1)
        gmsh.option.setNumber("Mesh.CharacteristicLengthMax", 0.05)
        gmsh.model.mesh.generate(2)
        gmsh.write(str(path))
    finally:
        gmsh.finalize()


@pytest.fixture(scope="module")
def block_file(tmp_path_factory):
    comm = MPI.COMM_WORLD
    path = None
    if comm.rank == 0:
        path = tmp_path_factory.mktemp("mesh") / "block.msh"
        _write_block(path)
    return comm.bcast(path, root=0)


def _obstacle():
    return ad.Plane(point=(0.0, -GAP), normal=(0.0, 1.0))


def test_the_file_scene_is_the_problem_written_by_hand(block_file):
    scene = scene_from_file(
        block_file, contact=31, displaced={13: (0.0, -PUSH)}, obstacle=_obstacle(), E=E, nu=NU
    )
    with ad.ADMMSolver(scene.problem(), petsc_options_prefix="file_") as solver:
        result = solver.solve()
    # the same problem, by DOLFINx's reader and forms written here
    data = gmshio.read_from_msh(block_file, MPI.COMM_WORLD, 0, gdim=2)
    msh, tags = data.mesh, data.facet_tags
    V = fem.functionspace(msh, ("Lagrange", 1, (2,)))
    u, v = ufl.TrialFunction(V), ufl.TestFunction(V)
    mu, lmbda = E / (2 * (1 + NU)), E * NU / ((1 + NU) * (1 - 2 * NU))
    eps = ufl.sym(ufl.grad(u))
    a = ufl.inner(2 * mu * eps + lmbda * ufl.tr(eps) * ufl.Identity(2), ufl.sym(ufl.grad(v)))
    L = ufl.dot(fem.Constant(msh, (0.0, 0.0)), v) * ufl.dx
    top = fem.locate_dofs_topological(V, 1, tags.find(13))
    bc = fem.dirichletbc(np.array([0.0, -PUSH]), top, V)
    by_hand = ad.ContactProblem(a * ufl.dx, L, [bc], tags, 31, _obstacle())
    with ad.ADMMSolver(by_hand, petsc_options_prefix="hand_") as solver:
        reference = solver.solve()
    assert result.converged and reference.converged
    force, expected = result.contact_force, reference.contact_force
    assert np.allclose(force, expected, rtol=1e-9, atol=1e-9 * np.abs(expected).max())
    # balance: the floor's force is the top's reaction, reversed
    reaction = result.reaction_force(13)
    assert np.allclose(force + reaction, 0.0, atol=1e-6 * abs(force[1]))
    # elasticity's bounds on the mean pressure of a block compressed by δ: a free
    # lateral strain (plane strain, E/(1 − ν²)) and none (E(1 − ν)/((1 + ν)(1 − 2ν)))
    strain = (PUSH - GAP) / HEIGHT
    low, high = E / (1 - NU**2) * strain, E * (1 - NU) / ((1 + NU) * (1 - 2 * NU)) * strain
    assert low < result.mean_pressure < high


@pytest.mark.timeout(300)
def test_run_mesh_writes_the_same_answer(block_file, tmp_path_factory):
    comm = MPI.COMM_WORLD
    out = tmp_path_factory.mktemp("run") if comm.rank == 0 else None
    out = comm.bcast(out, root=0)
    argv = ["run", "--mesh", str(block_file), "--contact", "31", "--displace", "13:0,-0.01"]
    argv += ["--plane", f"0,{-GAP}/0,1", "--E", str(E), "--nu", str(NU)]
    assert main([*argv, "--json", str(out / "s.json")]) == 0
    summary = json.loads((out / "s.json").read_text())
    scene = scene_from_file(
        block_file, contact=31, displaced={13: (0.0, -PUSH)}, obstacle=_obstacle(), E=E, nu=NU
    )
    with ad.ADMMSolver(scene.problem(), petsc_options_prefix="file2_") as solver:
        result = solver.solve()
    assert summary["converged"] and summary["scene"] == "block"
    assert np.allclose(summary["contact_force"], result.contact_force, rtol=1e-8)


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--contact", "7", "--plane", "0,0/0,1"], "no facets tagged [7]; its physical groups"),
        (["--plane", "0,0/0,1"], "--mesh needs --contact TAG"),
        (["--contact", "31"], "--mesh needs one obstacle"),
        (["--contact", "31", "--plane", "0,0,0/0,0,1"], "Plane is defined in 3D"),
        (["--contact", "31", "--fixed", "31", "--plane", "0,0/0,1"], "more than one role"),
    ],
)
def test_run_mesh_refuses_what_does_not_fit_with_a_clear_message(
    block_file, extra, message, capsys
):
    assert main(["run", "--mesh", str(block_file), "--fixed", "13", *extra]) == 1
    if MPI.COMM_WORLD.rank == 0:
        assert message in capsys.readouterr().err


def test_run_needs_a_scene_or_a_mesh(capsys):
    assert main(["run"]) == 1
    assert main(["run", "example1", "--contact", "3"]) == 1
    if MPI.COMM_WORLD.rank == 0:
        err = capsys.readouterr().err
        assert "run needs a scene" in err and "--contact go with --mesh FILE" in err


def test_a_missing_file_is_named(capsys):
    argv = ["run", "--mesh", "/no/such/part.msh", "--contact", "1", "--plane", "0,0/0,1"]
    assert main([*argv, "--fixed", "2"]) == 1
    if MPI.COMM_WORLD.rank == 0:
        assert "No mesh file '/no/such/part.msh'" in capsys.readouterr().err
