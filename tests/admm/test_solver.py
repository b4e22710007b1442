"""ADMM against an independent solver (SNES VI active-set Newton) and its own KKT test."""

import numpy as np
import pytest
from mpi4py import MPI

from admm_dolfinx import ADMMConvergenceError, ADMMSolver
from admm_dolfinx.linalg.petsc import factorization_count
from admm_dolfinx.scenes.library import example1
from admm_dolfinx.studies.baselines import solve_snes_vi

from conftest import rel_diff


def _global(problem, local):
    return np.concatenate(problem.comm.allgather(np.asarray(local)))


@pytest.mark.parametrize("h", [1 / 8, 1 / 16, 1 / 32])
def test_example1_matches_snes_vi(h):
    problem = example1(h=h).problem()
    with ADMMSolver(problem, penalty=3000.0, rtol=1e-11, max_iter=2000) as solver:
        result = solver.solve()
    ref = solve_snes_vi(problem)
    assert result.converged
    assert rel_diff(result.u.x.array, ref.u.x.array) <= 1e-6
    assert rel_diff(_global(problem, result.multiplier), _global(problem, ref.multiplier)) <= 1e-6
    assert ref.kkt.max() <= 1e-10
    assert result.kkt.max() <= 1e-6
    # The solution really is in contact, with a non-trivial active set.
    assert 0 < result.num_active < problem.num_contact_nodes
    assert np.all(result.multiplier >= 0.0)
    assert result.pressure.x.array.min() >= 0.0


def test_one_factorisation_per_penalty():
    problem = example1(h=1 / 16).problem()
    before = factorization_count()
    solver = ADMMSolver(problem, penalty=3000.0, rtol=1e-8)
    result = solver.solve()
    assert result.iterations > 10
    assert factorization_count() - before == 1  # from PETSc's log, not from our code
    solver.solve()  # a second solve at the same r reuses the factorisation
    assert factorization_count() - before == 1
    solver.set_penalty(2000.0)
    solver.solve()
    assert factorization_count() - before == 2
    solver.destroy()


def test_unconverged_solve_raises_with_partial_result():
    problem = example1(h=1 / 8).problem()
    solver = ADMMSolver(problem, penalty=3000.0, rtol=1e-8, max_iter=3)
    with pytest.raises(ADMMConvergenceError, match="did not converge in 3 iterations") as info:
        solver.solve()
    assert info.value.result.converged is False
    assert info.value.result.iterations == 3
    solver.destroy()


def test_scale_invariance_in_E():
    """E = 1 and E = 1e6 (with r and the load scaled alike) need the same iterations."""
    its = []
    for E in (1.0, 1e6):
        problem = example1(h=1 / 8, mesher="builtin", E=E, traction=10.0 * E / 2000.0).problem()
        with ADMMSolver(problem, penalty=1.5 * E, rtol=1e-8) as solver:
            its.append(solver.solve().iterations)
    assert its[0] == its[1]


def test_history_and_timings_are_recorded():
    problem = example1(h=1 / 8).problem()
    with ADMMSolver(problem, penalty=3000.0) as solver:
        result = solver.solve()
    assert len(result.history["du"]) == result.iterations
    last = [result.history[k][-1] for k in ("fpr", "feasibility", "complementarity", "equilibrium")]
    assert max(last) <= solver.settings.rtol
    # the in-loop residuals are honest: the independent KKT check agrees in magnitude
    assert result.kkt.max() <= 10 * solver.settings.rtol
    with ADMMSolver(problem, penalty=3000.0, mode="paper") as solver:
        paper = solver.solve()
    assert paper.history["du"][-1] <= 1e-5 and paper.history["dp"][-1] <= 1e-5
    assert paper.history["du"][-2] > 1e-5 or paper.history["dp"][-2] > 1e-5
    assert "converged" in result.summary()
    assert MPI.COMM_WORLD.allreduce(result.iterations, op=MPI.MAX) == result.iterations


@pytest.mark.parametrize(
    "options",
    [
        {"expert": {"alpha": 1.6, "anderson": 0}},
        {"expert": {"anderson": 5}},
        {"expert": {"alpha": 1.6, "anderson": 5}},
    ],
)
def test_accelerated_variants_match_snes_vi(options):
    problem = example1(h=1 / 16).problem()
    ref = solve_snes_vi(problem)
    with ADMMSolver(problem, penalty=2000.0, rtol=1e-10, max_iter=3000, **options) as solver:
        result = solver.solve()
    assert rel_diff(result.u.x.array, ref.u.x.array) <= 1e-7
    assert rel_diff(_global(problem, result.multiplier), _global(problem, ref.multiplier)) <= 1e-6
    assert result.kkt.max() <= 1e-8


def test_anderson_needs_fewer_iterations_at_equal_tolerance():
    problem = example1(h=1 / 16).problem()
    its = {}
    for name, options in {"plain": {"expert": {"anderson": 0, "alpha": 1.0}}, "aa": {}}.items():
        with ADMMSolver(problem, rtol=1e-8, polish=False, **options) as solver:
            its[name] = solver.solve().iterations
    assert its["aa"] * 2 < its["plain"]


@pytest.mark.parametrize(
    "options,message",
    [
        ({"expert": {"alpha": 2.0}}, "alpha"),
        ({"expert": {"alpha": 0.0}}, "alpha"),
        ({"expert": {"anderson": -1}}, "memory"),
        ({"mode": "fast"}, "mode"),
        ({"expert": {"stopping": "never"}}, "stopping"),
        ({"rtol": 0.0}, "rtol"),
    ],
)
def test_bad_solver_options(options, message):
    problem = example1(h=1 / 8, mesher="builtin").problem()
    with pytest.raises(ValueError, match=message):
        ADMMSolver(problem, penalty=1.0, **options)


def test_solver_package_options_reach_the_factorisation():
    """MUMPS reads its options when it factorises: they must still be set then."""
    problem = example1(h=1 / 8).problem()
    options = {"mat_mumps_icntl_14": 77}
    with ADMMSolver(problem, penalty=3000.0, petsc_options=options) as solver:
        factor = solver.operator.ksp.getPC().getFactorMatrix()
        assert factor.getMumpsIcntl(14) == 77
        solver.set_penalty(4000.0)  # a numeric refactorisation keeps them
        assert solver.operator.ksp.getPC().getFactorMatrix().getMumpsIcntl(14) == 77


@pytest.mark.parametrize("penalty", [3000.0, "auto"])  # ordinary, and condensed on 1 rank
def test_default_ordering_is_amf_in_2d_and_can_be_overridden(penalty):
    """2D: MUMPS's minimum-fill ordering (benchmarks/orderings.py); 3D: MUMPS's choice;
    what MUMPS ran (INFOG(7)) is what was asked for."""
    from admm_dolfinx.scenes.library import example3

    def ordering(problem, used=False, **options):
        with ADMMSolver(problem, penalty=penalty, **options) as solver:
            factor = solver.operator.ksp.getPC().getFactorMatrix()
            return factor.getMumpsInfog(7) if used else factor.getMumpsIcntl(7)

    problem = example1(h=1 / 8).problem()
    # AMF (2); with a Schur complement (condensed, one process), which AMF cannot
    # serve, AMD (0) on a mesh this small (METIS on large ones: test_condensed.py)
    condensed = penalty == "auto" and problem.comm.size == 1
    assert ordering(problem) == (0 if condensed else 2)
    assert ordering(problem, used=True) == (0 if condensed else 2)
    assert ordering(problem, petsc_options={"mat_mumps_icntl_7": 5}) == 5
    assert ordering(example3(level=0).problem()) == 7
