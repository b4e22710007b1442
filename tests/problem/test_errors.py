"""Bad input gets a clear error that names the problem and the fix (collectively under MPI)."""

import math

import numpy as np
import pytest
import ufl
from dolfinx import fem, mesh
from mpi4py import MPI

from admm_dolfinx import ADMMSolver, Ball, ContactProblem, Obstacle, Plane
from admm_dolfinx.scenes.library import example1
from admm_dolfinx.scenes.material import LinearElastic

from conftest import problem_from


@pytest.fixture(scope="module")
def scene():
    return example1(h=1 / 8, mesher="builtin")


def test_scalar_space(scene):
    Q = fem.functionspace(scene.mesh, ("Lagrange", 1))
    p, q = ufl.TrialFunction(Q), ufl.TestFunction(Q)
    with pytest.raises(ValueError, match="vector space with 2 components"):
        problem_from(scene, a=ufl.inner(ufl.grad(p), ufl.grad(q)) * ufl.dx, L=q * ufl.dx)


def test_p2_space(scene):
    V2 = fem.functionspace(scene.mesh, ("Lagrange", 2, (2,)))
    u, v = ufl.TrialFunction(V2), ufl.TestFunction(V2)
    with pytest.raises(ValueError, match="P1 Lagrange"):
        load = ufl.dot(ufl.as_vector((0.0, -1.0)), v) * ufl.dx
        problem_from(scene, a=scene.material.bilinear_form(u, v), L=load, bcs=[])


def test_not_a_form(scene):
    with pytest.raises(TypeError, match="bilinear UFL form"):
        problem_from(scene, a=scene.L)


def test_marker_without_facets(scene):
    message = r"No facets are tagged with contact marker 99.*\[1, 2, 3, 4\]"
    with pytest.raises(ValueError, match=message):
        problem_from(scene, contact_marker=99)


def test_marker_present_on_one_rank_only():
    """Facets on rank 0 only: valid, and no rank may hang or fail."""
    comm = MPI.COMM_WORLD
    msh = mesh.create_rectangle(comm, [[0, 0], [2, 1]], [8, 4])
    fdim = 1
    msh.topology.create_connectivity(fdim, 2)
    bottom = mesh.locate_entities_boundary(msh, fdim, lambda x: np.isclose(x[1], 0.0))
    left = mesh.locate_entities_boundary(msh, fdim, lambda x: np.isclose(x[0], 0.0))
    keep = bottom if comm.rank == 0 else bottom[:0]
    idx = np.unique(np.concatenate([keep, left]))
    values = np.where(np.isin(idx, keep), 3, 1).astype(np.int32)
    ft = mesh.meshtags(msh, fdim, idx, values)
    V = fem.functionspace(msh, ("Lagrange", 1, (2,)))
    u, v = ufl.TrialFunction(V), ufl.TestFunction(V)
    bc = fem.dirichletbc(np.zeros(2), fem.locate_dofs_topological(V, 1, ft.find(1)), V)
    f = fem.Constant(msh, np.array([0.0, -1.0]))
    problem = ContactProblem(
        LinearElastic(10.0, 0.3).bilinear_form(u, v),
        ufl.dot(f, v) * ufl.dx,
        [bc],
        ft,
        3,
        Plane((0, -0.01), (0, 1)),
    )
    assert problem.num_contact_nodes >= 1


@pytest.mark.parametrize("r", [0.0, -1.0, math.nan, math.inf])
def test_bad_penalty(scene, r):
    problem = problem_from(scene)
    with pytest.raises(ValueError, match="penalty r must be a positive finite number"):
        ADMMSolver(problem, penalty=r)


def test_penalty_of_wrong_type(scene):
    with pytest.raises(TypeError, match="penalty"):
        ADMMSolver(problem_from(scene), penalty="fast")


@pytest.mark.parametrize("max_iter", [0, -5])
def test_bad_max_iter(scene, max_iter):
    with pytest.raises(ValueError, match="max_iter must be at least 1"):
        ADMMSolver(problem_from(scene), penalty=1.0, max_iter=max_iter)


class _BadGap(Obstacle):
    def __init__(self, value):
        self.value = value

    def gap(self, x, n):
        g = np.full(x.shape[0], 0.01)
        g[x[:, 0] > 1.5] = self.value
        return g

    def signed_distance(self, x):
        return self.gap(x, None), np.tile([0.0, 1.0], (x.shape[0], 1))


@pytest.mark.parametrize("model", ["obstacle", "body"])
@pytest.mark.parametrize("value", [math.nan, -math.inf])
def test_bad_gap(scene, value, model):
    # a -inf gap along the body's normal: a node it cannot push out (explained as such)
    pattern = r"NaN or -inf at .* contact node|gap along the normal is -inf"
    with pytest.raises(ValueError, match=pattern):
        problem_from(scene, obstacle=_BadGap(value), contact_normal=model)


def test_infinite_gap_means_never_touching(scene):
    """A disc under the middle of Γ_C: in the paper's model the rays from the ends miss
    it (g = +inf), and that works."""
    problem = problem_from(
        scene, obstacle=Ball(center=(1.0, -0.31), radius=0.3), contact_normal="body"
    )
    gaps = np.concatenate(problem.comm.allgather(problem.contact.gap))
    assert np.isinf(gaps).any() and np.isfinite(gaps).any()
    with ADMMSolver(problem, penalty=3000.0, rtol=1e-9) as solver:
        result = solver.solve()
    assert result.num_active > 0
    assert result.kkt.max() < 1e-6
    lam = problem.contact.gap
    assert np.all(result.multiplier[np.isinf(lam)] == 0.0)


def test_facet_tags_from_another_mesh(scene):
    other = example1(h=1 / 8, mesher="builtin")
    with pytest.raises(ValueError, match="different mesh"):
        problem_from(scene, facet_tags=other.facet_tags)


def test_dirichlet_on_every_contact_dof(scene):
    V = scene.V
    dofs = fem.locate_dofs_topological(V, 1, scene.facet_tags.find(scene.contact_marker))
    bcs = [*scene.bcs, fem.dirichletbc(np.zeros(2), dofs, V)]
    with pytest.raises(ValueError, match="normal displacement fixed by the Dirichlet"):
        problem_from(scene, bcs=bcs)


def test_dirichlet_on_tangential_component_keeps_contact(scene):
    """Fixing u_x on Γ_C leaves the normal (y) motion free: still a contact problem."""
    V = scene.V
    dofs = fem.locate_dofs_topological(V.sub(0), 1, scene.facet_tags.find(scene.contact_marker))
    bcs = [*scene.bcs, fem.dirichletbc(0.0, dofs, V.sub(0))]
    problem = problem_from(scene, bcs=bcs)
    assert problem.num_contact_nodes == 16


def test_obstacle_dimension_mismatch(scene):
    with pytest.raises(ValueError, match="3D but the mesh is 2D"):
        problem_from(scene, obstacle=Plane((0, 0, 0), (0, 0, 1)))


@pytest.mark.parametrize("nu", [0.5, 0.6, -1.0])
def test_bad_poisson_ratio(nu):
    with pytest.raises(ValueError, match="Poisson ratio"):
        LinearElastic(1.0, nu)


@pytest.mark.parametrize(
    ("build", "kwargs", "message"),
    [
        ("example1", {"h": 0.0}, "h must be a positive finite length, got 0.0"),
        ("example1", {"h": math.nan, "mesher": "builtin"}, "h must be a positive finite"),
        ("example3", {"h_bottom": -1.0}, "h_bottom must be a positive finite length"),
        ("example3", {"level": -1}, "level must be an integer ≥ 0"),
        ("example2", {"level": 1.5}, "level must be an integer ≥ 0"),
        ("hertz", {"level": -2}, "level must be an integer ≥ 0"),
    ],
)
def test_bad_scene_parameters(build, kwargs, message):
    """Mesh sizes and levels are checked before gmsh sees them (a negative graded
    size aborted the process; a negative level of Example 3 was silently level 0)."""
    from admm_dolfinx import scenes

    with pytest.raises(ValueError, match=message):
        getattr(scenes, build)(**kwargs)


def test_a_gmsh_failure_on_rank_0_is_raised_on_every_rank():
    """gmsh builds on rank 0 alone: its failure (a planted one) reaches every rank as
    a RuntimeError naming the mesh, instead of leaving the others in the
    distribution of a mesh that never comes."""
    from admm_dolfinx.scenes.meshing import build_on_root

    def build(gmsh):
        raise ValueError("planted geometry error")

    with pytest.raises(RuntimeError, match="'broken' mesh: ValueError: planted"):
        build_on_root(MPI.COMM_WORLD, "broken", 2, build)


def test_bad_penalty_estimate_options(scene):
    """r*'s own options are checked before anything is factorised."""
    from admm_dolfinx import estimate_penalty

    problem = scene.problem()
    with pytest.raises(ValueError, match="penalty_tol must lie in"):
        ADMMSolver(problem, expert={"penalty_tol": 0.0})
    with pytest.raises(ValueError, match="penalty_tol must lie in"):
        ADMMSolver(problem, expert={"penalty_tol": math.nan})
    with pytest.raises(ValueError, match="max_it must be an integer ≥ 1"):
        estimate_penalty(problem, max_it=0)


def test_bad_sweep_and_bcs_arguments(scene):
    """A sweep's penalties are all checked before its first solve; a single
    DirichletBC where a list is expected is named as such."""
    from admm_dolfinx.studies.sweep import paper_penalty_grid, sample_penalty

    problem = scene.problem()
    for grid, message in [
        ([1e6, -1.0], "positive and finite; got \\[-1.0\\]"),
        ([], "non-empty 1D"),
        ([[1e6]], "non-empty 1D"),
        ([math.nan], "positive and finite"),
    ]:
        with pytest.raises(ValueError, match=message):
            sample_penalty(problem, grid)
    with pytest.raises(ValueError, match="num must be an integer ≥ 1"):
        paper_penalty_grid(1e6, 0)
    with pytest.raises(ValueError, match="E must be a positive"):
        paper_penalty_grid(-1.0, 10)
    with pytest.raises(TypeError, match="pass \\[bc\\], not bc"):
        problem_from(scene, bcs=scene.bcs[0])


def test_solve_after_destroy_is_a_clear_error():
    """A destroyed solver, or a solver whose problem was destroyed, says so."""
    problem = example1(h=1 / 4, mesher="builtin").problem()
    solver = ADMMSolver(problem)
    solver.destroy()
    with pytest.raises(RuntimeError, match="ADMMSolver has been destroyed"):
        solver.solve()
    solver = ADMMSolver(problem)
    problem.destroy()
    with pytest.raises(RuntimeError, match="ContactProblem of this solver has been destroyed"):
        solver.solve()
    solver.destroy()
