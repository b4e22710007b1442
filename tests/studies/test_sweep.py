"""The penalty sweep: the iteration count at each r, without a warning per slow sample."""

from __future__ import annotations

import logging

import pytest
from mpi4py import MPI

from admm_dolfinx import ADMMConvergenceError, ADMMSolver
from admm_dolfinx.scenes import example1
from admm_dolfinx.studies.sweep import sample_penalty

pytestmark = pytest.mark.timeout(300)


def _warnings(caplog):
    return [r for r in caplog.records if r.levelno >= logging.WARNING]


def test_a_sweep_of_poor_penalties_is_quiet(caplog):
    """Poor r are the sweep's data: their counts are returned, and no sample warns. The
    same slow solve outside a sweep does warn (the check could fail)."""
    problem = example1(h=1 / 8).problem()
    slow = 1e-3 * 2000.0  # far below r* ≈ E: hundreds of iterations
    with caplog.at_level(logging.WARNING):
        sweep = sample_penalty(problem, [slow, 2 * slow], max_iter=400)
    assert sweep.iterations.min() >= 300  # slow samples, as planned
    assert not _warnings(caplog)
    with caplog.at_level(logging.WARNING), ADMMSolver(problem, penalty=slow, mode="paper") as s:
        try:
            s.solve()
        except ADMMConvergenceError:
            pass  # slow enough not to converge: it warns all the same
    if MPI.COMM_WORLD.rank == 0:  # the package warns on rank 0
        assert any("slow" in r.getMessage() for r in _warnings(caplog))
