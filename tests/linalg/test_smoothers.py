"""A multigrid whose Chebyshev bounds fall short of the spectrum: found, made careful, solved.

On a strongly graded 3D mesh (a flat punch refined by solve_adaptive) PETSc's 10-step
estimate of λ_max(D⁻¹A_l) fell short of it, the V-cycle was indefinite and step 1
stopped with KSP_DIVERGED_INDEFINITE_PC. Here the same failure is made on a small mesh
by bounds the step-1 options narrow on purpose.
"""

from __future__ import annotations

import numpy as np
import pytest
from chebyshev_view import chebyshev_levels
from mpi4py import MPI
from petsc4py import PETSc

import admm_dolfinx as ad
from admm_dolfinx.linalg.petsc import check_solve, iterative_options
from admm_dolfinx.linalg.smoothers import CAREFUL_OPTIONS
from admm_dolfinx.operators.penalised import IterativeOperator
from admm_dolfinx.scenes import example3

pytestmark = pytest.mark.timeout(300)

#: Chebyshev bounds at half the estimated λ_max: an indefinite V-cycle.
NARROW = {"mg_levels_ksp_chebyshev_esteig": "0,0.05,0,0.5"}


@pytest.fixture(scope="module")
def problem():
    return example3(level=1).problem()


def test_the_step1_options_reach_the_smoothers_at_every_r(problem):
    """The smoothers estimate their bounds again at each new r, with the step-1 options
    (they were lost after the first set-up: PETSc's database holds them only then)."""
    operator = IterativeOperator(
        problem, "wide_", iterative_options({"mg_levels_ksp_chebyshev_esteig": "0,0.1,0,1.4"})
    )
    try:
        operator.set_up_hierarchy()
        for r in (3e6, 9e6):
            operator.set_penalty(r)
            levels = chebyshev_levels(operator.ksp, "wide")
            assert len(levels) >= 2
            assert all(level.how == "estimated via cg" for level in levels)
            assert all(level.widening == pytest.approx(1.4) for level in levels)
    finally:
        operator.destroy()


def _careful_widening() -> float:
    return float(str(CAREFUL_OPTIONS["ksp_chebyshev_esteig"]).split(",")[-1])


def test_an_indefinite_multigrid_is_made_careful_and_gives_the_factorised_answer(problem):
    """Narrow bounds break the first step-1 solve; its smoothers are then estimated
    carefully, for good, and the solve gives the factorised step 1's answer."""
    with ad.ADMMSolver(problem, step1="factorised", petsc_options_prefix="exact_") as solver:
        exact = solver.solve()
        reference = exact.u.x.petsc_vec.copy()
    with ad.ADMMSolver(
        problem, step1="iterative", petsc_options=NARROW, petsc_options_prefix="narrow_"
    ) as solver:
        result = solver.solve()
        operator = solver.operator
        assert isinstance(operator, IterativeOperator)
        assert operator.careful_bounds == 1  # once, then never again
        assert result.converged and result.step1 is not None
        assert result.step1.unconverged == 0
        levels = chebyshev_levels(operator.ksp, "careful")
        assert len(levels) >= 2
        for level in levels:
            assert level.widening == pytest.approx(_careful_widening())
            assert level.steps == CAREFUL_OPTIONS["esteig_ksp_max_it"]
        difference = result.u.x.petsc_vec.copy()
        difference.axpy(-1.0, reference)
        assert difference.norm() <= 1e-4 * reference.norm()  # both within the KKT tolerance
        assert np.allclose(result.contact_force, exact.contact_force, rtol=1e-4, atol=0.0)
        # a load step at the same r keeps the careful bounds: no second repair
        problem.update_load()
        solver.solve(warm_start=result)
        assert operator.careful_bounds == 1
    for vec in (reference, difference):
        vec.destroy()


def test_a_preconditioner_that_stays_indefinite_names_the_remedies():
    """What check_solve says when no careful estimate helps (an indefinite
    preconditioner of an SPD matrix: +1 and −3 on alternate rows): the reason, and
    what to change."""
    comm = MPI.COMM_WORLD
    matrix = PETSc.Mat().createAIJ(((None, 8 * comm.size), (None, 8 * comm.size)), comm=comm)
    matrix.setUp()
    start, end = matrix.getOwnershipRange()
    for i in range(start, end):
        matrix.setValue(i, i, 2.0 + i)
    matrix.assemble()

    class Indefinite:
        def apply(self, pc, x, y):
            x.copy(y)
            first, last = y.getOwnershipRange()
            y.array[:] *= np.where(np.arange(first, last) % 2 == 0, 1.0, -3.0)

    ksp = PETSc.KSP().create(comm)
    ksp.setOptionsPrefix("flip_")
    ksp.setOperators(matrix)
    ksp.setType(PETSc.KSP.Type.CG)
    pc = ksp.getPC()
    pc.setType(PETSc.PC.Type.PYTHON)
    pc.setPythonContext(Indefinite())
    b, x = matrix.createVecs()
    b.set(1.0)
    x.set(0.0)
    try:
        ksp.solve(b, x)
        with pytest.raises(RuntimeError, match="not positive definite") as error:
            check_solve(ksp, "a test system")
        assert "mg_levels_ksp_chebyshev_esteig" in str(error.value)
        assert "step1='factorised'" in str(error.value)
        assert "'flip_'" in str(error.value)
    finally:
        for obj in (ksp, matrix, b, x):
            obj.destroy()
