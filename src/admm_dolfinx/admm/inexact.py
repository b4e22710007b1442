"""The step-1 tolerance of an inexact ADMM (an iterative step 1).

Over-relaxed ADMM still converges when its subproblems are solved inexactly, provided
the errors are summable: Σ_k ε_k < ∞ (Eckstein & Bertsekas 1992, Theorem 8; the same
condition as for the inexact proximal point method, Rockafellar 1976). A fixed inner
tolerance is not summable: the outer residual stalls at the level of the inner error.
So the relative residual asked of the step-1 Krylov solve of iteration k is

    τ_k = max(τ_floor, min(τ_0 / k^q, σ r_{k−1})),

with r_{k−1} the previous scaled fixed-point residual (the quantity the outer iteration
is driving to zero) and τ_k a bound on CG's relative residual ‖b − Ax‖ / ‖b‖ (the
unpreconditioned one, :data:`~admm_dolfinx.linalg.petsc.CG_RESIDUAL_NORM`): σ r_{k−1}
keeps the inner error a fixed factor below what the outer iteration still has to gain,
and τ_0 / k^q (q > 1) makes the sequence summable whatever the outer rate; τ_floor
(:data:`TAU_FLOOR`) is where CG's relative residual meets round-off.

The factor σ is what one outer iteration can absorb, so it follows the outer rate
(the plan chooses it, :func:`~admm_dolfinx.admm.plan.make_plan`). A body held by its
Dirichlet conditions contracts by a large factor per iteration, and the looser
:data:`SIGMA_HELD` saves step-1 work at the cost of an iteration or two. A body that
the contact alone holds creeps (the ADMM builds its contact zone a few nodes per
iteration, r_k/r_{k−1} near 1), and each iteration's inner error must stay below
that iteration's small gain: :data:`SIGMA_FLOATING`. Both sides are measured by
``python benchmarks/inner_tolerance.py``.

Warm-started from the previous displacement, each solve then costs a few Krylov
iterations once the outer iteration settles.

The loop's residuals rest on identities of exact step-1 solves; the KKT residuals
recomputed from (u, λ) when the stopping test is met do not. If they show that the
step-1 error dominates, every tolerance is scaled down by :data:`TIGHTEN`
(:meth:`InexactRule.tighten`) and the iteration goes on; only when the tolerances have
reached :data:`TAU_FLOOR` is the solve reported as ``"inexact_step1"``.
``converged=True`` keeps its meaning: the recomputed residuals meet ``kkt_tol``.
"""

from __future__ import annotations

__all__ = ["SIGMA_FLOATING", "SIGMA_HELD", "TAU_0", "TAU_FLOOR", "InexactRule"]

#: The first (and largest) inner tolerance.
TAU_0 = 1e-2
#: The inner tolerance relative to the previous outer residual, for a body held by
#: its Dirichlet conditions (the outer iteration contracts fast)...
SIGMA_HELD = 3e-3
#: ...and for one that the contact alone holds (it creeps).
SIGMA_FLOATING = 3e-4
#: The summable envelope's exponent q.
DECAY = 1.5
#: The smallest tolerance: below it the relative residual of CG is round-off. It is
#: relative to ‖b‖, which a large prescribed displacement makes large against the
#: contact force; the force balance at rtol 1e-10 of such a body needs it this low.
TAU_FLOOR = 1e-15
#: Every τ_k is scaled by this when the KKT check finds the step-1 error too large.
TIGHTEN = 1e-2


class InexactRule:
    """The inner tolerances τ_k of an iterative step 1.

    Args:
        fixed: A fixed tolerance (``ksp_rtol`` in the user's ``petsc_options``), or None
            for the adaptive rule.
        sigma: σ, the inner tolerance relative to the previous outer residual (the
            plan's choice; the safe default is the tighter :data:`SIGMA_FLOATING`).
    """

    def __init__(self, fixed: float | None = None, sigma: float = SIGMA_FLOATING):
        if not 0.0 < sigma < 1.0:
            raise ValueError(f"the inexact rule's σ must lie in (0, 1), got {sigma}.")
        self.fixed = fixed
        self.sigma = sigma
        self.scale = 1.0
        self.tightened = 0
        self.last = float("inf")  # the tolerance last handed out

    def tolerance(self, k: int, last_residual: float | None) -> float:
        """τ_k for iteration k ≥ 1, given the previous fixed-point residual (None at first)."""
        if self.fixed is not None:
            self.last = self.fixed
            return self.fixed
        tau = TAU_0 / k**DECAY
        if last_residual is not None and last_residual == last_residual:  # not NaN
            tau = min(tau, self.sigma * last_residual)
        self.last = max(TAU_FLOOR, self.scale * tau)
        return self.last

    def tighten(self) -> bool:
        """Scale every tolerance down (the KKT check found the step-1 error too large).

        Returns:
            False if they cannot go lower (a fixed tolerance, or the solves already
            ran at :data:`TAU_FLOOR`): the step-1 error then stands.
        """
        if self.fixed is not None or self.last <= TAU_FLOOR:
            return False
        self.scale *= TIGHTEN
        self.tightened += 1
        return True
