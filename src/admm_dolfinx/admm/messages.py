"""What a finished solve tells its user: why it failed, or why it was slow, and the fix.

Each message is read off the result alone (its settings, plan, penalty, history and
recomputed KKT residuals), so the solver only decides *whether* to speak.
"""

from __future__ import annotations

import numpy as np

from admm_dolfinx.admm.result import ADMMResult

__all__ = ["SLOW_ITERATIONS", "failure_message", "slow_convergence_warning"]

#: A solve that needs this many iterations or more says so in ``result.warning``.
SLOW_ITERATIONS = 300


def _automatic_penalty(result: ADMMResult) -> bool:
    """Whether r came from the estimate (r* or the surface metric's), not by hand."""
    return result.penalty_estimate is not None or result.surface_penalty is not None


def failure_message(result: ADMMResult) -> str:
    """Why a solve did not converge, and what to do about it.

    Args:
        result: The partial result of a solve whose ``status`` is ``"max_iter"``,
            ``"inaccurate"`` or ``"inexact_step1"``.
    """
    k, h, r, s = result.kkt, result.history, result.penalty, result.settings
    residuals = (
        f"KKT residuals recomputed from (u, λ): penetration {k.primal_feasibility:.2e}, "
        f"complementarity {k.complementarity:.2e}, equilibrium {k.equilibrium:.2e}, "
        f"force balance {k.force_balance:.2e}"
    )
    hand = not _automatic_penalty(result)
    if result.status == "inexact_step1":
        return (
            f"ADMM's stopping test was met after {result.iterations} iterations, but the "
            f"equilibrium residual recomputed from (u, λ) is {k.equilibrium:.2e} where "
            f"the iteration's identity gives {h['equilibrium'][-1]:.2e}: the step-1 "
            f"solves are not exact (petsc_options {dict(s.petsc_options)}). Use the "
            "default factorisation, or drop ksp_rtol from petsc_options (the default "
            "ties the step-1 tolerance to the outer residual), or tighten it (≤ 1e-10). "
            "The partial result is attached as `err.result`."
        )
    if result.status == "inaccurate":
        return (
            f"ADMM's relative-change test was met after {result.iterations} iterations "
            f"at r = {r:.6g}, but the iteration had stagnated, not converged: {residuals}, "
            f"above kkt_tol = {s.kkt_tol:g}. "
            + (
                "r set by hand is far from the balanced penalty: use penalty='auto'. "
                if hand
                else "Use the 'kkt' stopping test (mode='accelerated'). "
            )
            + "The partial result is attached as `err.result`."
        )
    advice = (
        "use penalty='auto' (r set by hand is the usual cause of a slow ADMM), or increase max_iter"
        if hand
        else "increase max_iter"
    )
    step1 = result.step1
    if step1 is not None and step1.unconverged > 0:
        advice = (
            f"{step1.unconverged} of the {step1.solves} step-1 solves stopped at their "
            "Krylov iteration limit short of their tolerance, and more ADMM iterations "
            "do not mend the inner solver: raise ksp_max_it in petsc_options if you set "
            "it, give step 1 a stronger preconditioner there, or use "
            "step1='factorised' where a factorisation fits (a body that its Dirichlet "
            "conditions barely hold makes the system nearly singular: check them)"
        )
    elif isinstance(result.plan.ksp_rtol, float):
        advice = (
            f"the step-1 tolerance is fixed at ksp_rtol = {result.plan.ksp_rtol:g}, and "
            "the outer iteration stalls at the level of a fixed inner error: drop "
            "ksp_rtol from petsc_options (the default ties it to the outer residual), "
            "or " + advice
        )
    return (
        f"ADMM did not converge in {s.max_iter} iterations at r = {r:.6g} "
        f"({s.stopping!r} test at rtol = {s.rtol:.1e}; last residuals: fpr "
        f"{h['fpr'][-1]:.2e}, equilibrium {h['equilibrium'][-1]:.2e}, du "
        f"{h['du'][-1]:.2e}, dp {h['dp'][-1]:.2e}; {residuals}): {advice}. The partial "
        "result is attached as `err.result`."
    )


def slow_convergence_warning(result: ADMMResult) -> str:
    """A loud note when the iteration was slow, with its observed contraction.

    Args:
        result: A finished solve.

    Returns:
        The note, with advice that fits the solve's settings; empty below
        :data:`SLOW_ITERATIONS` iterations.
    """
    n = len(result.history["fpr"])
    if n < SLOW_ITERATIONS:
        return ""
    tail = np.asarray(result.history["fpr"][-20:], dtype=float)
    tail = tail[tail > 0]
    rate = float(np.exp(np.mean(np.diff(np.log(tail))))) if tail.size > 2 else float("nan")
    automatic = _automatic_penalty(result)
    origin = "automatic" if automatic else "given by hand"
    if not automatic:
        advice = "use penalty='auto' (r*), which balances the extreme modes."
    elif result.settings.anderson == 0:
        advice = (
            "try Anderson acceleration (expert={'anderson': 5}, the default of mode='accelerated')."
        )
    elif result.polish is None and result.plan.step1 != "iterative":
        advice = (
            "polish=True finishes with the exact contact set once it is found (where "
            "the contact alone holds the body, the usual cause)."
        )
    else:
        advice = (
            "the body may be held by the contact alone, or the contact zone badly "
            "resolved (refine the mesh near the contact)."
        )
    return (
        f"ADMM {'needed' if result.converged else 'ran'} {n} iterations (contraction of the "
        f"fixed-point residual ≈ {rate:.4f} per iteration) at r = {result.penalty:.6g} "
        f"({origin}). This is slow: {advice}"
    )
