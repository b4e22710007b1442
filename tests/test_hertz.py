"""Validation against Hertz's analytic solution (plane-strain cylinder on a rigid plane).

The discrete pressure converges to Hertz's at the observed rate, until the finite
cylinder's own O(a/R) difference from Hertz's half-space theory (about 0.4 % at
a/R = 1/80) takes over; the tests use the levels before that floor.
"""

import numpy as np
import pytest
from mpi4py import MPI

from admm_dolfinx import ADMMSolver
from admm_dolfinx.scenes import hertz
from admm_dolfinx.validation import hertz_errors, observed_rate


@pytest.fixture(scope="module")
def errors():
    out = []
    for level in range(4):
        scene = hertz(MPI.COMM_WORLD, level=level, half_width=0.1)
        problem = scene.problem()
        with ADMMSolver(problem, rtol=1e-9) as solver:
            result = solver.solve()
        out.append(hertz_errors(scene, problem, result.multiplier))
    return out


def test_pressure_profile_converges_at_first_order(errors):
    h = [e.h for e in errors]
    l2 = [e.l2_error for e in errors]
    assert np.all(np.diff(l2) < 0)
    assert observed_rate(h, l2) >= 0.8  # measured ≈ 1.0 (√-singular profile at ±a)


def test_peak_pressure_and_half_width(errors):
    for e in errors[1:]:
        assert abs(e.p0_error) <= 0.02
    for e in errors:
        assert e.a_error <= e.h  # the discrete contact zone brackets a within one element
