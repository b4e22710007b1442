"""User code that fails, or answers differently, on one rank only: never a hang.

An obstacle's gap, a callback and a user's Dirichlet conditions run on every rank. If
one rank raises, every rank raises; if one rank asks to stop, every rank stops. Each
test would hang under ``mpiexec -n 2`` without that (and then fail on its timeout).
Also: user code cannot corrupt the problem's data (read-only inputs), and garbage
collection is never collective.
"""

from __future__ import annotations

import gc

import numpy as np
import pytest
import ufl
from dolfinx import fem
from mpi4py import MPI

from admm_dolfinx import ADMMSolver, Obstacle, Plane
from admm_dolfinx.scenes.library import example1

from conftest import problem_from

pytestmark = [pytest.mark.timeout(60), pytest.mark.mpi3]
COMM = MPI.COMM_WORLD
LAST = COMM.size - 1


@pytest.fixture(scope="module")
def scene():
    return example1(COMM, h=1 / 8, mesher="builtin")


class FailsOnLastRank(Obstacle):
    def gap(self, x, n):
        if COMM.rank == LAST:
            raise ValueError("this rank's gap failed")
        return Plane((0.0, -0.01), (0.0, 1.0)).gap(x, n)

    def signed_distance(self, x):
        if COMM.rank == LAST:
            raise ValueError("this rank's gap failed")
        return Plane((0.0, -0.01), (0.0, 1.0)).signed_distance(x)


class WritesIntoItsInput(Obstacle):
    def gap(self, x, n):
        n *= -1.0  # corrupts the normals if it could
        return np.full(x.shape[0], 0.01)

    def signed_distance(self, x):
        x[:, 1] -= 1.0  # moves the nodes if it could
        return np.full(x.shape[0], 0.01), np.tile([0.0, 1.0], (x.shape[0], 1))


@pytest.mark.parametrize("model", ["obstacle", "body"])
def test_gap_raising_on_one_rank_raises_on_every_rank(scene, model):
    with pytest.raises(ValueError, match="gap failed"):
        problem_from(scene, obstacle=FailsOnLastRank(), contact_normal=model)


@pytest.mark.parametrize("model", ["obstacle", "body"])
def test_gap_cannot_modify_its_inputs(scene, model):
    with pytest.raises(ValueError, match="read-only"):
        problem_from(scene, obstacle=WritesIntoItsInput(), contact_normal=model)
    # and a good problem built afterwards has the right normals and nodes
    problem = problem_from(scene, contact_normal=model)
    assert np.allclose(problem.contact.normals, [0.0, -1.0])
    assert np.allclose(problem.contact.coordinates[:, 1], 0.0)


def test_update_obstacle_raising_on_one_rank_keeps_the_old_obstacle(scene):
    problem = problem_from(scene)
    gap = problem.contact.gap.copy()
    with pytest.raises(ValueError, match="gap failed"):
        problem.update_obstacle(FailsOnLastRank())
    assert np.array_equal(problem.contact.gap, gap) and problem.obstacle is scene.obstacle


def test_callback_raising_on_one_rank_raises_on_every_rank(scene):
    def callback(k, u, lam):
        if COMM.rank == LAST and k == 2:
            raise RuntimeError("this rank's callback failed")
        return False

    with ADMMSolver(problem_from(scene), polish=False) as solver:
        with pytest.raises(RuntimeError, match="callback failed"):
            solver.solve(callback=callback)
        # the solver is still usable afterwards
        assert solver.solve().converged


def test_callback_stopping_on_one_rank_stops_every_rank(scene):
    with ADMMSolver(problem_from(scene), polish=False) as solver:
        result = solver.solve(callback=lambda k, u, lam: COMM.rank == LAST and k == 3)
    assert result.status == "callback" and result.iterations == 3


def test_dirichlet_condition_on_another_space_is_refused(scene):
    """A P2 space, or an identical copy of V: DOLFINx's assembly would silently skip it."""
    for space in (
        fem.functionspace(scene.mesh, ("Lagrange", 2, (2,))),
        fem.functionspace(scene.mesh, ("Lagrange", 1, (2,))),
    ):
        dofs = fem.locate_dofs_topological(space, 1, scene.facet_tags.find(1))
        bc = fem.dirichletbc(np.zeros(2), dofs, space)
        with pytest.raises(ValueError, match=r"bcs\[0\].*not the displacement space"):
            problem_from(scene, bcs=[bc])


def test_nan_inputs_are_refused_up_front(scene):
    V = scene.V
    v = ufl.TestFunction(V)
    nan_load = ufl.dot(fem.Constant(scene.mesh, np.array([0.0, np.nan])), v) * ufl.dx
    with pytest.raises(ValueError, match=r"load vector.*NaN"):
        problem_from(scene, L=nan_load)
    inf_load = ufl.dot(fem.Constant(scene.mesh, np.array([np.inf, 0.0])), v) * ufl.dx
    with pytest.raises(ValueError, match=r"load vector.*NaN"):
        problem_from(scene, L=inf_load)
    dofs = fem.locate_dofs_topological(V, 1, scene.facet_tags.find(1))
    bad_bc = fem.dirichletbc(np.array([np.nan, 0.0]), dofs, V)
    with pytest.raises(ValueError, match=r"Dirichlet condition bcs\[0\].*NaN"):
        problem_from(scene, bcs=[bad_bc])

    class Absurd(Obstacle):
        def signed_distance(self, x):
            return np.full(x.shape[0], -1e300), np.tile([0.0, 1.0], (x.shape[0], 1))

    with pytest.raises(ValueError, match="deeper than the body's size"):
        problem_from(scene, obstacle=Absurd())


def test_nan_warm_start_is_refused(scene):
    problem = problem_from(scene)
    with ADMMSolver(problem) as solver:
        result = solver.solve()
        result.u.x.array[:] = np.nan
        with pytest.raises(ValueError, match=r"warm start.*NaN"):
            solver.solve(warm_start=result)


def test_nan_load_update_is_refused(scene):
    msh, V = scene.mesh, scene.V
    t = fem.Constant(msh, np.array([0.0, -10.0]))
    ds = ufl.Measure("ds", domain=msh, subdomain_data=scene.facet_tags)
    problem = problem_from(scene, L=ufl.dot(t, ufl.TestFunction(V)) * ds(2))
    with ADMMSolver(problem) as solver:
        t.value[1] = np.nan
        with pytest.raises(ValueError, match=r"load vector.*NaN"):
            solver.solve()


def test_garbage_collection_is_never_collective(scene):
    """A solver in a reference cycle, collected on one rank only, must not deadlock."""
    problem = problem_from(scene)
    solver = ADMMSolver(problem)
    solver.cycle = solver  # only the cycle collector can free it
    del solver
    if COMM.rank == 0:
        gc.collect()  # the other ranks do not collect now
    COMM.Barrier()
    # collective work goes on: it would deadlock if rank 0's collection had destroyed a
    # parallel PETSc object collectively
    with ADMMSolver(problem) as again:
        assert again.solve().converged
    gc.collect()


class InterruptedOnLastRank(Obstacle):
    """A user's obstacle whose evaluation is interrupted (Ctrl-C, sys.exit) on one rank."""

    def __init__(self, kind: type[BaseException]):
        self.kind = kind

    def signed_distance(self, x):
        if COMM.rank == LAST:
            raise self.kind("stopped by the user")
        return Plane((0.0, -0.01), (0.0, 1.0)).signed_distance(x)


@pytest.mark.parametrize("kind", [KeyboardInterrupt, SystemExit])
def test_an_interrupt_in_user_code_leaves_every_rank(scene, kind):
    """The rank that was interrupted re-raises its own interrupt; the others leave the
    collective call with an error that names it (they used to wait forever)."""
    expected = kind if COMM.rank == LAST else RuntimeError
    with pytest.raises(expected) as caught:
        problem_from(scene, obstacle=InterruptedOnLastRank(kind))
    if COMM.rank != LAST:
        assert f"{kind.__name__}" in str(caught.value) and f"rank {LAST}" in str(caught.value)
    # every rank is still in step: collective work goes on
    assert ADMMSolver(problem_from(scene)).solve().converged


def test_an_interrupt_in_the_callback_leaves_every_rank(scene):
    def callback(k, u, lam):
        if COMM.rank == LAST and k == 2:
            raise KeyboardInterrupt
        return False

    expected = KeyboardInterrupt if COMM.rank == LAST else RuntimeError
    with ADMMSolver(problem_from(scene), polish=False) as solver:
        with pytest.raises(expected):
            solver.solve(callback=callback)
        assert solver.solve().converged  # still usable, on every rank


@pytest.mark.skipif(COMM.size == 1, reason="settings differ between ranks only under MPI")
@pytest.mark.parametrize(
    "per_rank",
    [
        {"rtol": 1e-6 * 10.0**-COMM.rank},
        {"penalty": 1000.0 * (1 + COMM.rank)},
        {"max_iter": 100 + COMM.rank},
        {"petsc_options": {"mat_mumps_icntl_14": 20 + COMM.rank}},
        {"expert": {"alpha": 1.2 + 0.1 * COMM.rank}},
    ],
    ids=["rtol", "penalty", "max_iter", "petsc_options", "expert-alpha"],
)
def test_settings_that_differ_between_ranks_are_refused_on_every_rank(scene, per_rank):
    (name,) = per_rank.get("expert", per_rank)  # an expert setting is named itself
    with pytest.raises(ValueError, match=rf"settings differ between the MPI ranks \(.*{name}: "):
        ADMMSolver(problem_from(scene), **per_rank)


@pytest.mark.skipif(COMM.size == 1, reason="settings differ between ranks only under MPI")
def test_a_setting_invalid_on_one_rank_only_is_refused_on_every_rank(scene):
    rtol = -1.0 if COMM.rank == LAST else 1e-6
    with pytest.raises(ValueError, match="rtol must be a positive"):
        ADMMSolver(problem_from(scene), rtol=rtol)
    with ADMMSolver(problem_from(scene)) as solver:
        with pytest.raises(ValueError, match=r"differ between the MPI ranks \(.*rtol: "):
            solver.update_settings(rtol=1e-6 * 10.0**-COMM.rank)
        assert solver.settings.rtol == 1e-6  # unchanged, on every rank


@pytest.mark.skipif(COMM.size == 1, reason="settings differ between ranks only under MPI")
def test_estimate_penalty_arguments_that_differ_between_ranks_are_refused(scene):
    from admm_dolfinx import estimate_penalty

    with pytest.raises(ValueError, match=r"arguments differ between the MPI ranks \(tol: "):
        estimate_penalty(problem_from(scene), tol=0.01 * (1 + COMM.rank))
    with pytest.raises(ValueError, match="tol must lie in"):
        estimate_penalty(problem_from(scene), tol=2.0 if COMM.rank == LAST else 0.01)
