"""Load steps: ``update_load`` and ``update_obstacle`` keep r* and the factorisation, and
give the answer of a problem assembled afresh with the new data (serial and MPI)."""

import numpy as np
import pytest
import ufl
from dolfinx import fem, mesh
from mpi4py import MPI

from admm_dolfinx import ADMMSolver, ContactProblem, Obstacle, Plane
from admm_dolfinx.linalg.petsc import factorization_count

from conftest import gather_nodal, rel_diff

LEFT, TOP, BOTTOM = 1, 2, 3


def _block(comm=MPI.COMM_WORLD):
    """A 2 × 1 elastic block above a floor, with its facets tagged."""
    msh = mesh.create_rectangle(comm, [[0.0, 0.0], [2.0, 1.0]], [24, 12])
    marked = [
        (LEFT, lambda x: np.isclose(x[0], 0.0)),
        (TOP, lambda x: np.isclose(x[1], 1.0)),
        (BOTTOM, lambda x: np.isclose(x[1], 0.0)),
    ]
    facets, values = [], []
    for tag, where in marked:
        found = mesh.locate_entities_boundary(msh, 1, where)
        facets.append(found)
        values.append(np.full(found.size, tag, dtype=np.int32))
    facets, values = np.concatenate(facets), np.concatenate(values)
    facets, first = np.unique(facets, return_index=True)  # corners: keep one tag
    tags = mesh.meshtags(msh, 1, facets, values[first])
    V = fem.functionspace(msh, ("Lagrange", 1, (2,)))
    return msh, tags, V


def _problem(msh, tags, V, traction, top_displacement, obstacle):
    """Contact problem with a traction and a prescribed top displacement, as Constants."""
    u, v = ufl.TrialFunction(V), ufl.TestFunction(V)
    E, nu = 2000.0, 0.3
    mu, lmbda = E / (2 * (1 + nu)), E * nu / ((1 + nu) * (1 - 2 * nu))
    eps = ufl.sym(ufl.grad(u))
    sigma = 2 * mu * eps + lmbda * ufl.tr(eps) * ufl.Identity(2)
    a = ufl.inner(sigma, ufl.sym(ufl.grad(v))) * ufl.dx
    ds = ufl.Measure("ds", domain=msh, subdomain_data=tags)
    t = fem.Constant(msh, np.array([traction, 0.0]))
    L = ufl.dot(t, v) * ds(LEFT)
    u_top = fem.Constant(msh, np.array([0.0, -top_displacement]))
    top = fem.locate_dofs_topological(V, 1, tags.find(TOP))
    bcs = [fem.dirichletbc(u_top, top, V)]
    return ContactProblem(a, L, bcs, tags, BOTTOM, obstacle), t, u_top


def _floor(height, slope=0.0):
    """The floor y = height − slope·x (its normal points up, into the body)."""
    return Plane(point=(0.0, height), normal=(slope, 1.0))


def _fresh_solution(penalty, traction, top_displacement, obstacle, mesh_data):
    problem, _, _ = _problem(*mesh_data, traction, top_displacement, obstacle)
    with ADMMSolver(problem, penalty=penalty, rtol=1e-10, max_iter=3000) as solver:
        result = solver.solve()
    return result


def _global(problem, local):
    return np.concatenate(problem.comm.allgather(np.asarray(local)))


def test_load_and_dirichlet_steps_reuse_the_factorisation_and_match_fresh_problems():
    mesh_data = _block()
    floor = _floor(-0.002)
    problem, t, u_top = _problem(*mesh_data, 0.0, 0.001, floor)
    solver = ADMMSolver(problem, rtol=1e-10, max_iter=3000)  # r* by the default estimate
    first = solver.solve()
    estimate, r = solver.penalty_estimate, solver.penalty
    active = [first.num_active]
    for traction, pushed in [(0.0, 0.004), (-30.0, 0.004), (-30.0, 0.008)]:
        t.value[:] = (traction, 0.0)
        u_top.value[:] = (0.0, -pushed)
        problem.update_load()
        before = factorization_count()
        result = solver.solve()
        assert factorization_count() == before  # no new factorisation, no new r*
        assert solver.penalty == r and solver.penalty_estimate is estimate
        assert result.converged and result.kkt.max() <= 1e-8
        fresh = _fresh_solution(r, traction, pushed, floor, mesh_data)
        assert rel_diff(result.u.x.array, fresh.u.x.array) <= 1e-8
        lam, lam_fresh = _global(problem, result.multiplier), _global(problem, fresh.multiplier)
        assert rel_diff(lam, lam_fresh) <= 1e-7
        active.append(result.num_active)
    # the steps really change the contact: pushing further closes more of the gap
    assert active[0] < active[1] and active[2] < active[3]
    solver.destroy()


def test_obstacle_steps_reuse_the_factorisation_and_match_fresh_problems():
    mesh_data = _block()
    problem, _, _ = _problem(*mesh_data, 0.0, 0.004, _floor(-0.003, 0.002))
    solver = ADMMSolver(problem, rtol=1e-10, max_iter=3000)
    active = [solver.solve().num_active]
    for height in (-0.002, -0.001):
        obstacle = _floor(height, 0.002)
        problem.update_obstacle(obstacle)
        assert problem.obstacle is obstacle
        before = factorization_count()
        result = solver.solve()
        assert factorization_count() == before
        fresh = _fresh_solution(solver.penalty, 0.0, 0.004, obstacle, mesh_data)
        assert rel_diff(result.u.x.array, fresh.u.x.array) <= 1e-8
        active.append(result.num_active)
    assert active[0] < active[1] < active[2]  # a rising floor touches more nodes
    solver.destroy()


class _NaNBelowMiddle(Obstacle):
    """A broken obstacle: NaN gap at the nodes with x < 1 (on whichever rank owns them)."""

    def signed_distance(self, x):
        return np.where(x[:, 0] < 1.0, np.nan, 0.1), np.tile([0.0, 1.0], (x.shape[0], 1))


def test_bad_obstacle_update_raises_and_keeps_the_previous_one():
    mesh_data = _block()
    floor = _floor(-0.002)
    problem, _, _ = _problem(*mesh_data, 0.0, 0.001, floor)
    gap = problem.contact.gap.copy()
    with pytest.raises(ValueError, match="NaN or -inf"):
        problem.update_obstacle(_NaNBelowMiddle())
    with pytest.raises(ValueError, match="3D but the mesh is 2D"):
        problem.update_obstacle(Plane(point=(0, 0, 0), normal=(0, 0, 1)))
    with pytest.raises(TypeError, match=r"must be an admm_dolfinx\.Obstacle"):
        problem.update_obstacle("floor")
    assert problem.obstacle is floor
    np.testing.assert_array_equal(problem.contact.gap, gap)


def test_warm_start_from_the_previous_step_gives_the_same_answer_in_fewer_iterations():
    mesh_data = _block()
    problem, t, u_top = _problem(*mesh_data, -20.0, 0.004, _floor(-0.002, 0.002))
    # the ADMM iteration itself (polished, both solves take the minimum: 2 iterations)
    solver = ADMMSolver(problem, rtol=1e-10, max_iter=3000, polish=False)
    previous = solver.solve()
    t.value[:] = (-22.0, 0.0)  # a small load increment
    u_top.value[:] = (0.0, -0.0042)
    problem.update_load()
    cold = solver.solve()
    warm = solver.solve(warm_start=previous)
    assert warm.converged and warm.kkt.max() <= 1e-8
    assert rel_diff(warm.u.x.array, cold.u.x.array) <= 1e-8
    assert warm.iterations < cold.iterations
    solver.destroy()


def test_warm_start_from_another_problem_is_refused():
    mesh_data = _block()
    problem, _, _ = _problem(*mesh_data, 0.0, 0.004, _floor(-0.002))
    other, _, _ = _problem(*_block(), 0.0, 0.004, _floor(-0.002))
    with ADMMSolver(other, penalty=3000.0) as solver:
        foreign = solver.solve()
    with ADMMSolver(problem, penalty=3000.0) as solver:
        with pytest.raises(
            ValueError, match=r"must be an ADMMResult \(or a WarmStart\) of this problem"
        ):
            solver.solve(warm_start=foreign)
        with pytest.raises(
            ValueError, match=r"must be an ADMMResult \(or a WarmStart\) of this problem"
        ):
            solver.solve(warm_start="previous")


def test_update_load_refuses_a_changed_stiffness():
    msh, tags, V = _block()
    E = fem.Constant(msh, 2000.0)
    u, v = ufl.TrialFunction(V), ufl.TestFunction(V)
    a = E * ufl.inner(ufl.sym(ufl.grad(u)), ufl.sym(ufl.grad(v))) * ufl.dx
    L = ufl.dot(fem.Constant(msh, np.array([0.0, -1.0])), v) * ufl.dx
    top = fem.locate_dofs_topological(V, 1, tags.find(TOP))
    bcs = [fem.dirichletbc(np.zeros(2), top, V)]
    problem = ContactProblem(a, L, bcs, tags, BOTTOM, _floor(-0.01))
    problem.update_load()  # nothing changed: fine
    E.value = 4000.0
    with pytest.raises(ValueError, match="bilinear form `a` changed"):
        problem.update_load()


def test_solve_picks_up_changed_load_data_without_update_load():
    mesh_data = _block()
    floor = _floor(-0.002, 0.002)
    problem, t, u_top = _problem(*mesh_data, 0.0, 0.003, floor)
    with ADMMSolver(problem, rtol=1e-10, max_iter=3000) as solver:
        solver.solve()
        t.value[:] = (-25.0, 0.0)  # no update_load(): solve() notices the new data
        u_top.value[:] = (0.0, -0.005)
        result = solver.solve()
        fresh = _fresh_solution(solver.penalty, -25.0, 0.005, floor, mesh_data)
        assert rel_diff(result.u.x.array, fresh.u.x.array) <= 1e-8
        assert problem.sync_load() is False  # already current


def test_sync_load_sees_function_valued_dirichlet_data_and_a_changed_stiffness():
    msh, tags, V = _block()
    E = fem.Constant(msh, 2000.0)
    u, v = ufl.TrialFunction(V), ufl.TestFunction(V)
    a = E * ufl.inner(ufl.sym(ufl.grad(u)), ufl.sym(ufl.grad(v))) * ufl.dx
    L = ufl.dot(fem.Constant(msh, np.array([0.0, 0.0])), v) * ufl.dx
    motion = fem.Function(V)
    top = fem.locate_dofs_topological(V, 1, tags.find(TOP))
    problem = ContactProblem(a, L, [fem.dirichletbc(motion, top)], tags, BOTTOM, _floor(-0.01))
    assert problem.sync_load() is False
    motion.x.array[1::2] = -0.02  # the top moves down
    assert problem.sync_load() is True
    assert problem.load_norm > 0.0  # the lifting of the new Dirichlet values
    E.value = 3000.0
    with pytest.raises(ValueError, match="bilinear form `a` changed"):
        problem.sync_load()
    with ADMMSolver(problem, penalty=1e4) as solver, pytest.raises(ValueError, match="`a`"):
        solver.solve()


def test_warm_started_load_steps_agree_with_a_serial_run():
    """The whole step sequence on all ranks against the same on each rank alone."""
    finals = []
    for comm in (MPI.COMM_SELF, MPI.COMM_WORLD):
        problem, t, u_top = _problem(*_block(comm), -20.0, 0.003, _floor(-0.002, 0.002))
        with ADMMSolver(problem, penalty=14000.0, rtol=1e-12, max_iter=3000) as solver:
            result = solver.solve()
            for step in (1, 2):
                t.value[:] = (-20.0 - 5.0 * step, 0.0)
                u_top.value[:] = (0.0, -0.003 - 0.0005 * step)  # picked up by solve()
                problem.update_obstacle(_floor(-0.002 + 0.0005 * step, 0.002))
                result = solver.solve(warm_start=result)
        finals.append((gather_nodal(result.u), result.iterations))
    (coords_serial, u_serial), its_serial = finals[0]
    (coords_parallel, u_parallel), its_parallel = finals[1]
    np.testing.assert_allclose(coords_parallel, coords_serial)
    assert rel_diff(u_parallel, u_serial) <= 1e-10
    assert abs(its_parallel - its_serial) <= 1  # the same iterates up to round-off
