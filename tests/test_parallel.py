"""Serial against parallel: the distributed solve equals a COMM_SELF solve to round-off.

Run under ``mpiexec -n 2`` and ``-n 3`` (see the Makefile); serially there is nothing
to compare and the tests are skipped.
"""

import dataclasses

import numpy as np
import pytest
from mpi4py import MPI

from admm_dolfinx import ADMMSolver
from admm_dolfinx.scenes.library import example1

from conftest import gather_nodal, rel_diff

pytestmark = [pytest.mark.mpi3]

parallel_only = pytest.mark.skipif(MPI.COMM_WORLD.size == 1, reason="needs mpiexec -n >= 2")


def _solve(comm, h, mesher, penalty=3000.0, **options):
    problem = example1(comm, h=h, mesher=mesher).problem()
    with ADMMSolver(problem, penalty=penalty, rtol=1e-10, max_iter=2000, **options) as solver:
        result = solver.solve()
    coords, u = gather_nodal(result.u)
    c = problem.contact
    xc = np.concatenate(comm.allgather(c.coordinates))
    lam = np.concatenate(comm.allgather(result.multiplier))
    order = np.lexsort(np.round(xc, 10).T[::-1])
    return result, coords, u, xc[order], lam[order]


@parallel_only
@pytest.mark.parametrize(
    "mesher,options",
    [
        ("gmsh", {"mode": "paper"}),
        ("builtin", {"mode": "paper"}),
        ("gmsh", {}),
        ("gmsh", {"expert": {"alpha": 1.6, "anderson": 5}}),
    ],
)
def test_parallel_matches_serial(mesher, options):
    par, xp, up, cp, lp = _solve(MPI.COMM_WORLD, 1 / 16, mesher, **options)
    ser, xs, us, cs, ls = _solve(MPI.COMM_SELF, 1 / 16, mesher, **options)
    # Contact facets span process boundaries: make sure the partition really cuts Γ_C.
    owners = MPI.COMM_WORLD.allgather(par.multiplier.size > 0)
    assert sum(owners) >= 2
    np.testing.assert_allclose(xp, xs, atol=1e-12)
    np.testing.assert_allclose(cp, cs, atol=1e-12)
    # the same iterate sequence, up to round-off
    assert par.iterations == ser.iterations
    assert par.history["accelerated"] == ser.history["accelerated"]
    for key in ("fpr", "equilibrium", "du"):
        np.testing.assert_allclose(par.history[key], ser.history[key], rtol=1e-6, atol=1e-14)
    assert rel_diff(up, us) <= 1e-10
    assert rel_diff(lp, ls) <= 1e-10


@parallel_only
def test_parallel_auto_penalty_matches_serial():
    """penalty="auto" in 2D: r* dense on both; the serial ADMM solves with the condensed
    factorisation, the distributed one with a factorisation of A + r*K. Both polish
    (rank 0 solves the dense active-set problem), at the same iteration."""
    par, _, up, _, lp = _solve(MPI.COMM_WORLD, 1 / 16, "gmsh", penalty="auto")
    ser, _, us, _, ls = _solve(MPI.COMM_SELF, 1 / 16, "gmsh", penalty="auto")
    assert par.penalty == pytest.approx(ser.penalty, rel=1e-10)
    assert par.iterations == ser.iterations
    assert par.history["accelerated"] == ser.history["accelerated"]
    assert dataclasses.replace(par.polish, time=0.0) == dataclasses.replace(ser.polish, time=0.0)
    assert par.polish.polished_at == par.iterations
    assert rel_diff(up, us) <= 1e-10
    assert rel_diff(lp, ls) <= 1e-10


@parallel_only
def test_parallel_surface_metric_matches_serial():
    """3D default (surface metric): r*, β, r and the iterates equal the serial ones.

    At penalty_tol ≤ 1e-6 λ_min and λ_max come from factorisations (the multigrid λ_max
    of the default tolerance depends on the partition at the eigenvalue tolerance);
    μ_max's layer solves start from a partition-independent vector. Step 2's surface
    QP is distributed, with the iterates of the serial method, so only round-off
    differs.
    """
    from admm_dolfinx.scenes.library import example3

    results = {}
    for name, comm in (("par", MPI.COMM_WORLD), ("ser", MPI.COMM_SELF)):
        problem = example3(comm, level=1).problem()
        with ADMMSolver(
            problem, rtol=1e-10, expert={"penalty_method": "factorised", "penalty_tol": 1e-8}
        ) as solver:
            result = solver.solve()
        _, u = gather_nodal(result.u)
        results[name] = (result, u)
    (par, up), (ser, us) = results["par"], results["ser"]
    assert par.plan.metric == ser.plan.metric == "surface"
    for key in ("lambda_min", "lambda_max", "beta", "mu_max", "r"):
        assert par.surface_penalty.as_dict()[key] == pytest.approx(
            ser.surface_penalty.as_dict()[key], rel=1e-9
        )
    assert par.iterations == ser.iterations
    assert par.history["accelerated"] == ser.history["accelerated"]
    for key in ("fpr", "equilibrium", "du"):
        np.testing.assert_allclose(par.history[key], ser.history[key], rtol=1e-6, atol=1e-14)
    assert rel_diff(up, us) <= 1e-10
