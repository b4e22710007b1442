"""The ADMM iteration for unilateral contact (Koko 2019, Algorithm 2).

With the lumped contact mass M, nodal normals N and the gap g (design.md §1–2), one
iteration is

    (A + r NᵀMN) u^{k+1} = f + NᵀM (r p^k − λ^k)       (step 1: one solve)
    p^{k+1} = min(N u^{k+1} + λ^k / r, g)               (step 2: node-wise projection)
    λ^{k+1} = max(λ^k + r (N u^{k+1} − g), 0)           (step 3: multiplier update)

The matrix A_r = A + r NᵀMN is fixed while r is fixed: it is factorised once (MUMPS
Cholesky by default) and every iteration is one forward/backward substitution.

Stopping (the paper's test): the relative changes ‖u^{k+1} − u^k‖/‖u^{k+1}‖ and
‖p^{k+1} − p^k‖/‖p^{k+1}‖ both fall below ``rtol``.  After the loop the relative KKT
residuals (:mod:`admm_dolfinx.kkt`) are computed and stored in the result.

Failure policy: a solve that reaches ``max_iter`` raises :class:`ADMMConvergenceError`;
the partial result is attached to the exception as ``err.result``.  A returned result
is always a converged one.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt
from dolfinx import fem
from dolfinx.common import Timer

from admm_dolfinx._logging import get_logger
from admm_dolfinx.kkt import KKTResiduals, compute_kkt_residuals
from admm_dolfinx.operators import PenalisedOperator
from admm_dolfinx.penalty import DEFAULT_PENALTY_TOL, PenaltyEstimate, estimate_penalty
from admm_dolfinx.petsc import unique_prefix
from admm_dolfinx.problem import ContactProblem

__all__ = ["ADMMConvergenceError", "ADMMResult", "ADMMSolver"]

logger = get_logger(__name__)

#: Default tolerance of the relative-change test. With it, Example 1 needs the
#: iteration counts of the paper's Table 1 (19 at r̄ and 35 at r* for h = 1/8, against
#: our 19 and 34), so it is taken to be the paper's tolerance.
DEFAULT_RTOL = 1e-5


@dataclass
class ADMMResult:
    """Outcome of :meth:`ADMMSolver.solve`.

    Attributes:
        u: Displacement, a Function on the problem's space.
        pressure: Contact pressure λ ≥ 0 as a P1 scalar Function, zero off Γ_C.
        converged: Whether the stopping test was met (always True for a returned
            result; False only on the result attached to an ADMMConvergenceError).
        iterations: Number of ADMM iterations (= step-1 solves).
        penalty: The penalty parameter r that was used.
        history: Per-iteration lists: ``du`` and ``dp`` (relative changes of u and p),
            ``primal`` (‖Nu − p‖/‖Nu‖), ``active`` (global number of nodes with λ > 0).
        timings: Wall-clock seconds: ``assembly`` (problem operators), ``operator``
            (A + rK), ``factorization``, ``iterations``, ``kkt``, ``total``.
        kkt: Relative KKT residuals of (u, λ).
        multiplier: λ at the owned contact nodes (local array).
        num_active: Global number of contact nodes with λ > 0.
        num_contact_nodes: Global number m of contact nodes.
    """

    u: fem.Function
    pressure: fem.Function
    converged: bool
    iterations: int
    penalty: float
    history: dict[str, list[float]]
    timings: dict[str, float]
    kkt: KKTResiduals
    multiplier: npt.NDArray[np.float64]
    num_active: int
    num_contact_nodes: int
    extra: dict[str, Any] = field(default_factory=dict)

    def summary(self) -> str:
        """A short human-readable report (what the demos print)."""
        status = "converged" if self.converged else "NOT CONVERGED"
        k = self.kkt
        t = self.timings
        est = self.extra.get("penalty_estimate")
        how = (
            f" (r* from λ_min {est['lambda_min']:.4g}, λ_max {est['lambda_max']:.4g}, "
            f"{est['solves']} solves)"
            if est
            else ""
        )
        lines = [
            f"ADMM {status} in {self.iterations} iterations, r = {self.penalty:.6g}{how}",
            f"  contact nodes m = {self.num_contact_nodes}, active (λ > 0) = {self.num_active}",
            f"  max pressure = {self.extra.get('max_pressure', float('nan')):.6g}",
            "  KKT residuals (relative): "
            f"feasibility {k.primal_feasibility:.2e}, complementarity "
            f"{k.complementarity:.2e}, equilibrium {k.equilibrium:.2e}",
            "  time [s]: " + ", ".join(f"{name} {value:.3f}" for name, value in t.items()),
        ]
        return "\n".join(lines)


class ADMMConvergenceError(RuntimeError):
    """Raised when ADMM does not meet its stopping test within ``max_iter`` iterations.

    Attributes:
        result: The (unconverged) result at the last iterate, ``converged=False``.
    """

    def __init__(self, message: str, result: ADMMResult):
        super().__init__(message)
        self.result = result


def _check_penalty(r: Any) -> float:
    try:
        value = float(r)
    except (TypeError, ValueError):
        raise TypeError(f"penalty must be a positive number or 'auto', got {r!r}.") from None
    if not (math.isfinite(value) and value > 0.0):
        raise ValueError(
            f"penalty r must be a positive finite number, got {r!r}. Use penalty='auto' "
            "for the automatic choice r* = 1/sqrt(λ_min λ_max), or a value of the order "
            "of Young's modulus."
        )
    return value


def _relative_change(change: float, reference: float) -> float:
    if change == 0.0:
        return 0.0
    return change / reference if reference > 0.0 else math.inf


class ADMMSolver:
    """ADMM for frictionless contact with a fixed penalty r and a reused factorisation.

    Args:
        problem: The contact problem.
        penalty: Penalty parameter r > 0, or ``"auto"`` for r* = 1/sqrt(λ_min λ_max)
            from :func:`~admm_dolfinx.penalty.estimate_penalty` (the default).
        rtol: Tolerance of the paper's relative-change stopping test (> 0); the
            default 1e-5 reproduces the paper's iteration counts.
        max_iter: Maximum number of iterations (≥ 1).
        penalty_tol: Eigenvalue tolerance of the r* estimate (``penalty="auto"``).
        petsc_options: Options of the step-1 solver, overriding MUMPS Cholesky
            (``{"pc_type": "lu"}``, ``{"mat_mumps_icntl_14": 50}``, ...).
        petsc_options_prefix: Options prefix of the step-1 KSP; a unique one by default.

    Raises:
        ValueError: For r ≤ 0, NaN or inf, ``rtol`` ≤ 0 or ``max_iter`` < 1.

    The solver owns PETSc objects; call :meth:`destroy` (or use it as a context
    manager) to free them deterministically.
    """

    def __init__(
        self,
        problem: ContactProblem,
        *,
        penalty: float | str = "auto",
        rtol: float = DEFAULT_RTOL,
        max_iter: int = 1000,
        penalty_tol: float = DEFAULT_PENALTY_TOL,
        petsc_options: Mapping[str, Any] | None = None,
        petsc_options_prefix: str | None = None,
    ):
        if not isinstance(problem, ContactProblem):
            raise TypeError(f"problem must be a ContactProblem, got {type(problem).__name__}.")
        if isinstance(max_iter, bool) or not isinstance(max_iter, int | np.integer):
            raise TypeError(f"max_iter must be an int, got {max_iter!r}.")
        if max_iter < 1:
            raise ValueError(f"max_iter must be at least 1, got {max_iter}.")
        rtol = float(rtol)
        if not (math.isfinite(rtol) and rtol > 0.0):
            raise ValueError(f"rtol must be a positive finite number, got {rtol!r}.")
        auto = isinstance(penalty, str) and penalty == "auto"
        if not auto:
            penalty = _check_penalty(penalty)
        self.problem = problem
        self.rtol = rtol
        self.max_iter = int(max_iter)
        self.prefix = petsc_options_prefix or unique_prefix("admm_")
        self.operator = PenalisedOperator(problem, self.prefix, petsc_options)
        #: The r* estimate when ``penalty="auto"`` (None otherwise).
        self.penalty_estimate: PenaltyEstimate | None = None
        if auto:
            # r* is computed with this solver's own operator (factorised at an auxiliary
            # r_a), so the factorisation at r* below reuses its symbolic analysis.
            self.penalty_estimate = estimate_penalty(
                problem,
                tol=penalty_tol,
                operator=self.operator,
                petsc_options=petsc_options,
                petsc_options_prefix=self.prefix + "penalty_",
            )
            penalty = self.penalty_estimate.r
        self.set_penalty(penalty)

    # ------------------------------------------------------------------ set-up
    @property
    def penalty(self) -> float:
        """The current penalty parameter r."""
        return self.operator.penalty

    def set_penalty(self, r: float) -> None:
        """Set r, form A_r = A + r NᵀMN and factorise it (once per r).

        A new r keeps the sparsity pattern, so the symbolic factorisation is reused and
        only the numeric factorisation is redone.

        Args:
            r: Penalty parameter, > 0.
        """
        self.operator.set_penalty(_check_penalty(r))

    @property
    def ksp(self):
        """The step-1 KSP (factorised A + rNᵀMN)."""
        return self.operator.ksp

    # ------------------------------------------------------------------ solve
    def solve(self) -> ADMMResult:
        """Run ADMM from u⁰ = 0, λ⁰ = 0, p⁰ = min(0, g).

        Returns:
            The converged result.

        Raises:
            ADMMConvergenceError: If the stopping test is not met within ``max_iter``
                iterations (the partial result is ``err.result``).
            RuntimeError: If a linear solve fails.
        """
        problem = self.problem
        c = problem.contact
        r = self.penalty
        g = c.gap
        t_start = time.perf_counter()

        u = fem.Function(problem.V, name="displacement")
        x = u.x.petsc_vec
        x_old = problem.create_vector()
        b0 = problem.create_vector()
        b = problem.create_vector()
        x_old.set(0.0)
        problem.assemble_rhs(r, b0)

        p = np.minimum(0.0, g)
        lam = np.zeros_like(g)
        history: dict[str, list[float]] = {"du": [], "dp": [], "primal": [], "active": []}
        converged = False
        iterations = 0
        logger.info(
            "ADMM: m = %d contact nodes, r = %.6g, rtol = %.1e, prefix '%s'",
            c.num_global,
            r,
            self.rtol,
            self.prefix,
        )
        try:
            with Timer("admm_dolfinx: iterations"):
                t0 = time.perf_counter()
                for k in range(1, self.max_iter + 1):
                    iterations = k
                    b0.copy(b)
                    problem.add_normal_force(b, r * p - lam)
                    self.operator.solve(b, x)
                    nu = problem.apply_normal(x)
                    with np.errstate(invalid="ignore"):
                        p_new = np.minimum(nu + lam / r, g)
                        lam = np.maximum(lam + r * (nu - g), 0.0)

                    x_old.axpy(-1.0, x)
                    du = _relative_change(x_old.norm(), x.norm())
                    dp = _relative_change(
                        problem.global_norm(p_new - p), problem.global_norm(p_new)
                    )
                    primal = _relative_change(
                        problem.global_norm(nu - p_new), problem.global_norm(nu)
                    )
                    active = int(problem.comm.allreduce(int(np.count_nonzero(lam > 0.0))))
                    p = p_new
                    x.copy(x_old)
                    for key, val in zip(history, (du, dp, primal, active), strict=True):
                        history[key].append(val)
                    logger.info(
                        "ADMM %4d: du %.3e  dp %.3e  |Nu-p| %.3e  active %d  r %.4g",
                        k,
                        du,
                        dp,
                        primal,
                        active,
                        r,
                    )
                    if du <= self.rtol and dp <= self.rtol:
                        converged = True
                        break
                t_iter = time.perf_counter() - t0
            u.x.scatter_forward()

            t0 = time.perf_counter()
            kkt = compute_kkt_residuals(problem, x, lam)
            t_kkt = time.perf_counter() - t0
        finally:
            for vec in (x_old, b0, b):
                vec.destroy()

        pressure = problem.pressure_function(lam)
        timings = {
            "assembly": problem.timings.get("assembly", 0.0),
            "penalty": self.penalty_estimate.time if self.penalty_estimate else 0.0,
            "operator": self.operator.timings["operator"],
            "factorization": self.operator.timings["factorization"],
            "iterations": t_iter,
            "kkt": t_kkt,
        }
        timings["total"] = (
            timings["assembly"]
            + timings["penalty"]
            + timings["operator"]
            + timings["factorization"]
            + time.perf_counter()
            - t_start
        )
        result = ADMMResult(
            u=u,
            pressure=pressure,
            converged=converged,
            iterations=iterations,
            penalty=r,
            history=history,
            timings=timings,
            kkt=kkt,
            multiplier=lam,
            num_active=history["active"][-1],
            num_contact_nodes=c.num_global,
            extra={
                "max_pressure": problem.global_norm(lam, np.inf),
                "penalty_estimate": self.penalty_estimate.as_dict()
                if self.penalty_estimate
                else None,
            },
        )
        if not converged:
            raise ADMMConvergenceError(
                f"ADMM did not converge in {self.max_iter} iterations at r = {r:.6g}: "
                f"relative changes du = {history['du'][-1]:.2e}, dp = {history['dp'][-1]:.2e} "
                f"> rtol = {self.rtol:.1e}. Increase max_iter, or use penalty='auto' if r "
                "was set by hand (a poor r slows ADMM down). The partial result is "
                "attached as `err.result`.",
                result,
            )
        logger.info("%s", result.summary())
        return result

    # ------------------------------------------------------------------ lifetime
    def destroy(self) -> None:
        """Free the KSP and the operator A + rNᵀMN."""
        self.operator.destroy()

    def __enter__(self) -> ADMMSolver:
        return self

    def __exit__(self, *exc) -> None:
        self.destroy()

    def __del__(self):
        try:
            self.destroy()
        except Exception:  # pragma: no cover - interpreter shutdown
            pass
