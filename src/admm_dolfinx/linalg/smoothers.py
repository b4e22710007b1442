"""A multigrid's Chebyshev smoothers: their eigenvalue bounds, and a solve that survives bad ones.

A Chebyshev smoother of level l damps the error in the interval [λ_lo, λ_hi] of the
spectrum of D⁻¹A_l it is given; above λ_hi its polynomial grows. The smoother, and
with it the V-cycle, is symmetric positive definite only if λ_hi lies above
λ_max(D⁻¹A_l). PETSc estimates λ_max by a few CG steps from a noisy start and widens
the estimate by 10 %. Where the element sizes of a mesh span decades (a 3D mesh that
:func:`~admm_dolfinx.solve_adaptive` refined near a sharp contact edge) those steps can
miss the top of the spectrum by more than that: the V-cycle is then indefinite, and CG
stops with ``KSP_DIVERGED_INDEFINITE_PC`` (or crawls to its iteration limit) although
A + rK is positive definite.

:func:`solve_spd` catches that case: it estimates every level's bounds again with
:data:`CAREFUL_OPTIONS` (more CG steps, a wider margin), solves again from the same
start, and the smoothers keep the careful estimate for every later set-up of the
hierarchy (a new r, a new guess of the active-set walk). A V-cycle that is still
indefinite is reported by :func:`~admm_dolfinx.linalg.petsc.check_solve`, with the
remedies.
"""

from __future__ import annotations

from collections.abc import Iterator

from petsc4py import PETSc

from admm_dolfinx._logging import get_logger
from admm_dolfinx.linalg.petsc import prefixed_options

__all__ = ["CAREFUL_OPTIONS", "estimate_bounds_afresh", "set_up_smoother", "solve_spd"]

logger = get_logger(__name__)

#: A careful estimate of a Chebyshev smoother's bounds, under the smoother's own options
#: prefix: 50 CG steps (PETSc's default is 10) and the estimated λ_max widened by 30 %
#: (PETSc's default: 10 %), the interval's lower end a tenth of it as before.
CAREFUL_OPTIONS: dict[str, object] = {
    "esteig_ksp_max_it": 50,
    "ksp_chebyshev_esteig": "0,0.1,0,1.3",
}
#: The attribute that marks a smoother whose bounds are estimated carefully.
_CAREFUL = "admm_dolfinx_careful_bounds"


def _chebyshev_smoothers(pc: PETSc.PC) -> Iterator[PETSc.KSP]:
    """The Chebyshev smoothers of a multigrid preconditioner (none for another one)."""
    if pc.getType() not in (PETSc.PC.Type.GAMG, PETSc.PC.Type.MG):
        return
    for level in range(1, pc.getMGLevels()):  # level 0 is the coarse solve
        smoother = pc.getMGSmoother(level)
        if smoother.getType() == PETSc.KSP.Type.CHEBYSHEV:
            yield smoother


def _is_careful(smoother: PETSc.KSP) -> bool:
    return bool(smoother.getAttr(_CAREFUL))


def estimate_bounds_afresh(smoother: PETSc.KSP) -> None:
    """Make a Chebyshev smoother estimate its eigenvalue bounds on its next set-up.

    GAMG's first set-up hands each Chebyshev smoother the extreme eigenvalues of
    D⁻¹A_l found while smoothing the prolongator; they belong to the operator of that
    set-up. PETSc's own set-up at a new r (with the interpolation kept) has the
    smoothers estimate them again, by a few Krylov iterations on the new operator;
    recreating the Chebyshev context does the same here, the options for the smoother
    in PETSc's database applied again (and :data:`CAREFUL_OPTIONS` over them for a
    smoother :func:`solve_spd` made careful). A fresh context each time keeps the
    estimate a function of the operator alone: a kept estimator's next estimate
    depends on its history.
    """
    smoother.setType(PETSc.KSP.Type.RICHARDSON)
    smoother.setType(PETSc.KSP.Type.CHEBYSHEV)
    if _is_careful(smoother):
        with prefixed_options(smoother.getOptionsPrefix() or "", CAREFUL_OPTIONS):
            smoother.setFromOptions()
    else:
        smoother.setFromOptions()


def set_up_smoother(smoother: PETSc.KSP, operator: PETSc.Mat) -> None:
    """Set a level's smoother (or the coarse solve) up on its changed operator."""
    operator.setOption(PETSc.Mat.Option.SPD, True)  # axpy forgets it
    if smoother.getType() == PETSc.KSP.Type.CHEBYSHEV:
        estimate_bounds_afresh(smoother)
    smoother.setOperators(operator, operator)
    smoother.setUp()  # as PCSetUp_MG: Jacobi, Chebyshev's bounds, coarse LU


def _make_careful(pc: PETSc.PC) -> bool:
    """Estimate every Chebyshev level's bounds carefully, from now on; collective.

    Returns:
        False if there was nothing to make careful (no Chebyshev level, or every one
        careful already).
    """
    smoothers = [s for s in _chebyshev_smoothers(pc) if not _is_careful(s)]
    for smoother in smoothers:
        smoother.setAttr(_CAREFUL, True)
        set_up_smoother(smoother, smoother.getOperators()[0])
    return bool(smoothers)


def solve_spd(
    ksp: PETSc.KSP, b: PETSc.Vec, x: PETSc.Vec, what: str, *, limit_is_ours: bool = True
) -> bool:
    """``ksp.solve(b, x)`` for an SPD system, solved again if its multigrid failed.

    A multigrid whose smoothers' bounds fall short of the spectrum shows itself in
    one of two ways: CG meets a negative curvature of the preconditioner
    (``KSP_DIVERGED_INDEFINITE_PC``), or it crawls to its iteration limit
    (``KSP_DIVERGED_ITS``; only a sign where the limit is the package's own, large
    one: a limit the user set is reached by design). Either way, the first time, the
    Chebyshev levels' bounds
    are estimated carefully (:data:`CAREFUL_OPTIONS`, kept from then on) and the
    system is solved again from the same start. x is the initial guess (with a
    nonzero initial guess set on ``ksp``) and the solution. The caller checks the
    KSP's converged reason afterwards, as after any solve: a failure that careful
    bounds do not cure stands. Collective.

    Args:
        ksp: The Krylov solver (CG, say) of a symmetric positive definite system.
        b: The right-hand side.
        x: The initial guess, then the solution.
        what: What is solved, for the log.
        limit_is_ours: Whether the iteration limit is the package's (not the user's
            ``ksp_max_it``): reaching it then counts as a failed multigrid.

    Returns:
        Whether the bounds were made careful (and the system solved again).
    """
    failures = {
        PETSc.KSP.ConvergedReason.DIVERGED_INDEFINITE_PC: "it is not positive definite",
    }
    if limit_is_ours:
        failures[PETSc.KSP.ConvergedReason.DIVERGED_MAX_IT] = "CG reached its iteration limit"
    pc = ksp.getPC()
    start = None
    if any(not _is_careful(s) for s in _chebyshev_smoothers(pc)):
        start = x.copy()
    try:
        ksp.solve(b, x)
        # the reason is a global one (CG's inner products): every rank agrees
        failure = failures.get(ksp.getConvergedReason())
        if start is None or failure is None or not _make_careful(pc):
            return False
        logger.warning(
            "The multigrid of %s failed (%s): its Chebyshev smoothers' eigenvalue bounds "
            "fall short of the spectrum, as on a strongly graded mesh. They are estimated "
            "again, from now on, with %s CG steps and the transform %s, and the system "
            "is solved again.",
            what,
            failure,
            CAREFUL_OPTIONS["esteig_ksp_max_it"],
            CAREFUL_OPTIONS["ksp_chebyshev_esteig"],
        )
        start.copy(x)
        ksp.solve(b, x)
        return True
    finally:
        if start is not None:
            start.destroy()
