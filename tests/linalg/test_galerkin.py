"""The kept multigrid hierarchy moved to a new r as A_l + r K_l: the coarse operators PETSc
would recompute, the same CG iterations, and a fresh set-up where the sum cannot apply."""

from __future__ import annotations

import numpy as np
import pytest
from chebyshev_view import chebyshev_levels
from petsc4py import PETSc

from admm_dolfinx.linalg.petsc import iterative_options
from admm_dolfinx.operators.penalised import IterativeOperator, PenalisedOperator
from admm_dolfinx.operators.surface_metric import SurfaceMetric
from admm_dolfinx.scenes import example3

pytestmark = pytest.mark.timeout(300)


def _coarse_operators(operator: IterativeOperator) -> list[PETSc.Mat]:
    pc = operator.ksp.getPC()
    return [pc.getMGSmoother(level).getOperators()[0] for level in range(pc.getMGLevels())]


def _petscs_set_up(operator: IterativeOperator, r: float) -> None:
    """PETSc's own set-up at r, its hierarchy kept: the Galerkin products recomputed."""
    operator._drop_coarse()
    PenalisedOperator.set_penalty(operator, r)


def _galerkin_products() -> int:
    return PETSc.Log.Event("PCGAMG Gal l00").getPerfInfo()["count"]


def _solve(operator: IterativeOperator, problem) -> tuple[int, PETSc.Vec]:
    b = problem.create_vector()
    problem.assemble_rhs(0.0, b)
    x = b.duplicate()
    x.set(0.0)
    operator.set_tolerance(1e-10)
    operator.solve(b, x)
    b.destroy()
    return operator.last_iterations, x


def _assert_same_hierarchy(moved: IterativeOperator, recomputed: IterativeOperator, problem):
    levels = _coarse_operators(moved)
    assert len(levels) == len(_coarse_operators(recomputed)) >= 3
    for mine, petscs in zip(levels, _coarse_operators(recomputed), strict=True):
        difference = mine.duplicate(copy=True)
        difference.axpy(-1.0, petscs)
        assert difference.norm() <= 1e-12 * petscs.norm()
        difference.destroy()
    # Every Chebyshev smoother estimated its bounds on its new operator, as PETSc's
    # set-up has them do, instead of keeping the first set-up's (from smoothing the
    # prolongator at the old r). The estimates agree with PETSc's to the accuracy of a
    # 10-step Krylov estimate from a random start (which PETSc draws per estimator).
    mine = chebyshev_levels(moved.ksp, "moved")
    petscs = chebyshev_levels(recomputed.ksp, "petsc")
    assert len(mine) == len(petscs) == len(levels) - 1
    for level, petscs_level in zip(mine, petscs, strict=True):
        assert level.how.startswith("estimated via")
        assert level.largest == pytest.approx(petscs_level.largest, rel=0.05)
    (its_moved, x_moved), (its_recomputed, x_recomputed) = (
        _solve(moved, problem),
        _solve(recomputed, problem),
    )
    assert abs(its_moved - its_recomputed) <= 2
    x_moved.axpy(-1.0, x_recomputed)
    assert x_moved.norm() <= 1e-8 * x_recomputed.norm()


@pytest.fixture(scope="module")
def problem():
    return example3(level=1).problem()


def test_a_new_r_moves_the_coarse_operators_to_petscs_galerkin_products(problem):
    """Set up at r = 0, then at r* and at 3 r*: the coarse operators are those of PETSc's
    recomputed set-up (P_lᵀ(A + rK)P_l) to round-off, with no Galerkin product of A."""
    PETSc.Log.begin()
    moved = IterativeOperator(problem, "moved_", iterative_options(None))
    recomputed = IterativeOperator(problem, "recomputed_", iterative_options(None))
    try:
        moved.set_penalty(0.0)
        recomputed.set_penalty(0.0)
        for r in (3e6, 9e6):
            before = _galerkin_products()
            moved.set_penalty(r)
            assert _galerkin_products() == before  # no product of A recomputed
            _petscs_set_up(recomputed, r)
            _assert_same_hierarchy(moved, recomputed, problem)
    finally:
        moved.destroy()
        recomputed.destroy()


def test_a_new_penalty_matrix_is_summed_at_r_zero_and_set_up_afresh_otherwise(problem):
    """The surface metric's Nᵀ(M + βL_Γ)N replaces NᵀMN: at r = 0 its products are formed
    and summed; after a set-up at r > 0 the coarse operators hold r NᵀMN's products, so
    PETSc sets the preconditioner up again. Both give PETSc's operators."""
    metric = SurfaceMetric(problem)
    for first in (0.0, 1e6):
        moved = IterativeOperator(problem, "moved_", iterative_options(None))
        recomputed = IterativeOperator(problem, "recomputed_", iterative_options(None))
        try:
            for operator in (moved, recomputed):  # the same hierarchy, built at r = first
                operator.set_penalty(first)
                operator.use_penalty_matrix(metric.penalty_matrix(0.3), "Nᵀ(M + βL_Γ)N")
            PETSc.Log.begin()
            before = _galerkin_products()
            moved.set_penalty(3e6)
            assert _galerkin_products() - before == (0 if first == 0.0 else 1)
            _petscs_set_up(recomputed, 3e6)
            _assert_same_hierarchy(moved, recomputed, problem)
        finally:
            moved.destroy()
            recomputed.destroy()


def test_a_changed_active_set_adds_its_projected_change_to_the_hierarchy():
    """The iterative active-set polish moves its multigrid from one guess's Â to the
    next by adding P_lᵀ Δ P_l (Δ on the rows and columns of the nodes that moved): the
    coarse operators of PETSc's set-up on the new Â to round-off, without a Galerkin
    product of the whole Â, and the same solution."""
    from admm_dolfinx import ADMMSolver
    from admm_dolfinx.admm.polish_sparse import SparsePolish
    from admm_dolfinx.linalg.galerkin import sparse_difference
    from admm_dolfinx.scenes import hertz_sphere

    problem = hertz_sphere(level=1).problem()
    with ADMMSolver(problem) as solver:
        lam = solver.solve().multiplier
    moved, recomputed = (
        SparsePolish(problem, f"{name}_", iterative_options(None)) for name in ("moved", "fresh")
    )
    recomputed._updates = False  # PETSc's set-up on each Â, its interpolation kept
    PETSc.Log.begin()
    try:
        for share in (0.5, 0.1, 0.0):  # growing guesses of the contact set
            active = lam > share * problem.global_norm(lam, np.inf)
            before = _galerkin_products()
            nu_moved, lam_moved, _ = moved._equality_solution(active, moved.solve_rtol)
            products = _galerkin_products() - before
            nu_fresh, lam_fresh, _ = recomputed._equality_solution(active, recomputed.solve_rtol)
            assert products == (1 if share == 0.5 else 0)  # the first set-up only
            levels = [p._ksp.getPC() for p in (moved, recomputed)]
            assert levels[0].getMGLevels() == levels[1].getMGLevels() >= 3
            for level in range(levels[0].getMGLevels()):
                mine, petscs = (pc.getMGSmoother(level).getOperators()[0] for pc in levels)
                difference = mine.duplicate(copy=True)
                difference.axpy(-1.0, petscs)
                assert difference.norm() <= 1e-12 * petscs.norm()
                difference.destroy()
            assert np.allclose(lam_moved, lam_fresh, atol=1e-7 * np.abs(lam_fresh).max())
            assert np.allclose(nu_moved, nu_fresh, atol=1e-7 * np.abs(nu_fresh).max())
        # Δ holds the changed entries only, and old + Δ is the new matrix
        old = moved._matrix.duplicate(copy=True)
        new = old.duplicate(copy=True)
        new.setValueLocal(0, 0, 1.0, addv=PETSc.InsertMode.ADD_VALUES)
        new.assemble()
        delta = sparse_difference(new, old)
        assert problem.comm.allreduce(delta.getInfo()["nz_used"]) == problem.comm.size
        old.axpy(1.0, delta, structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN)
        old.axpy(-1.0, new)
        assert old.norm() == 0.0
        for matrix in (old, new, delta):
            matrix.destroy()
    finally:
        moved.destroy()
        recomputed.destroy()


def test_a_refused_update_sets_the_polish_multigrid_up_afresh(monkeypatch):
    """Where the projected change cannot be added, every rank sets the multigrid up
    again on Â, and the polish goes on to the same answer."""
    import admm_dolfinx.admm.polish_sparse as polish_sparse
    from admm_dolfinx import ADMMSolver
    from admm_dolfinx.scenes import hertz_sphere

    problem = hertz_sphere(level=0).problem()
    with ADMMSolver(problem, step1="iterative") as solver:
        expected = solver.solve()
    monkeypatch.setattr(polish_sparse, "add_to_hierarchy", lambda *args: False)
    with ADMMSolver(problem, step1="iterative") as solver:
        result = solver.solve()
        assert solver.polisher._updates is (result.polish.rounds == 1)
    assert result.polish.polished_at == 2 and result.kkt.max() <= 1e-6
    u, v = result.u.x.petsc_vec, expected.u.x.petsc_vec
    assert (u - v).norm() <= 1e-8 * v.norm()
