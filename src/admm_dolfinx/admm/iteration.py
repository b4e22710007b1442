"""One solve's iteration: its state, one evaluation of z ↦ T(z), and the next state.

The state is z = (p, λ). An evaluation is step 1 (one solve with A + NᵀRN), steps 2–3
(:mod:`admm_dolfinx.admm.step2`) and the residuals of T(z)
(:mod:`admm_dolfinx.admm.residuals`). The next state is T(z), or a proposal made from it:
an Anderson extrapolation, or the exact solution for the guessed contact set from a
polisher. A proposal is safeguarded: if its evaluation does not lower the fixed-point
residual of the last accepted state, it is rejected and that state's T(z) is taken
instead (the rejected evaluation still counts as an iteration).

The stopping test, its confirmation by recomputed KKT residuals and the callback are
the solver's (:mod:`admm_dolfinx.admm.solver`): this module only iterates.
"""

from __future__ import annotations

import logging
import time
from typing import TYPE_CHECKING

import numpy as np
from dolfinx import fem
from petsc4py import PETSc

from admm_dolfinx._logging import get_logger, progress
from admm_dolfinx.admm.anderson import AndersonMixer
from admm_dolfinx.admm.inexact import InexactRule
from admm_dolfinx.admm.polish_sparse import SparsePolish
from admm_dolfinx.admm.residuals import HISTORY_KEYS, IterationResiduals, ResidualMeter
from admm_dolfinx.admm.result import Step1Info
from admm_dolfinx.operators.penalised import IterativeOperator

if TYPE_CHECKING:
    from admm_dolfinx.admm.solver import ADMMSolver

__all__ = ["PROGRESS_SECONDS", "Iteration"]

# the solver's logger: a user's logging configuration for the solver covers its loop
logger = get_logger("admm_dolfinx.admm.solver")

#: ``history["accelerated"]`` codes: what the evaluated state was.
REJECTED, PLAIN, ANDERSON, POLISHED = -1, 0, 1, 2
_NOTES = {PLAIN: "", ANDERSON: " (Anderson)", POLISHED: " (polished)"}
#: Seconds between the progress lines of a long solve (logged at INFO, or shown in a
#: terminal where logging is not set up: :func:`admm_dolfinx._logging.progress`; every
#: iteration is logged at DEBUG).
PROGRESS_SECONDS = 10.0


class Iteration:
    """The iteration of one solve; collective.

    Args:
        solver: The solver (its problem, settings, r, step 1, steps 2–3, polisher, plan).
        z: The starting state (p, λ) at the owned contact nodes, concatenated.
        u_start: The starting displacement (copied).
        previous_residual: The fixed-point residual a warm start ended at (an iterative
            step 1's first tolerance follows it), or None.
    """

    def __init__(
        self,
        solver: ADMMSolver,
        z: np.ndarray,
        u_start: PETSc.Vec,
        previous_residual: float | None,
    ):
        problem, s = solver.problem, solver.settings
        self.problem, self.settings, self.r = problem, s, solver.penalty
        self.step, self.step1, self.polisher = solver._step, solver._step1, solver.polisher
        self.m = problem.contact.gap.size
        #: The displacement of the last evaluation.
        self.u = fem.Function(problem.V, name="displacement")
        self._b0, self._b = problem.create_vector(), problem.create_vector()
        try:  # a failure here (collective) frees the work vectors made so far
            problem.assemble_rhs(self.r, self._b0)
            self.step.reset(problem.contact.gap, self._b0, self._b, self.r)
            if self.polisher is not None:
                self.polisher.reset()
            self.meter = ResidualMeter(problem, self.r, u_start, z[: self.m])
        except BaseException:
            self._b0.destroy()
            self._b.destroy()
            raise
        self.mixer = (
            AndersonMixer(s.anderson, self.meter.weights, problem.comm) if s.anderson else None
        )
        # an iterative step 1: the inexact ADMM's inner tolerances, and its work so far
        self.inexact: InexactRule | None = None
        if isinstance(self.step1, IterativeOperator):
            plan = solver.plan
            if isinstance(plan.ksp_rtol, float):
                self.inexact = InexactRule(plan.ksp_rtol)
            else:
                assert plan.inner_sigma is not None
                self.inexact = InexactRule(sigma=plan.inner_sigma)
            op = self.step1
            self._work_before = (op.iterations, op.solves, op.unconverged, op.solve_time)
        self.last_residual = previous_residual if self.inexact is not None else None
        #: The state the next evaluation starts from, and what it is.
        self.z, self.proposal = z, PLAIN
        #: (T(z), its residual) of the last accepted state.
        self.accepted: tuple[np.ndarray, float] | None = None
        #: The iteration whose evaluated state was a polisher's, accepted.
        self.polished_at: int | None = None
        self.iterations = 0
        #: λ⁺ of the last evaluation (the contact pressure), at the owned contact nodes.
        self.multiplier = z[self.m :]
        self.history: dict[str, list[float]] = {key: [] for key in (*HISTORY_KEYS, "accelerated")}
        self._rejected = False
        self._started = time.perf_counter()
        self._next_progress = self._started + PROGRESS_SECONDS

    def evaluate(self, k: int) -> IterationResiduals:
        """Iteration k: T(z) from step 1 and steps 2–3, its residuals, logged; collective."""
        problem, s, r, m = self.problem, self.settings, self.r, self.m
        self.iterations = k
        p_in, lam_in = self.z[:m], self.z[m:]
        x = self.u.x.petsc_vec
        # step 1: (A + NᵀRN) u = f + Nᵀ(R p − M λ)
        self._b0.copy(self._b)
        problem.add_normal_force(self._b, r * p_in - lam_in)
        self.step.add_force(self._b, p_in, r)
        if self.inexact is not None:
            assert isinstance(self.step1, IterativeOperator)
            tolerance = self.inexact.tolerance(k, self.last_residual)
            polisher = self.polisher
            if (
                self.proposal == POLISHED
                and isinstance(polisher, SparsePolish)
                and polisher.displacement is not None
            ):
                # the polished state is a fixed point and its u the solution of this
                # step 1: start there, and solve as accurately as the polisher did
                x.array_w[:] = polisher.displacement
                x.ghostUpdate(PETSc.InsertMode.INSERT, PETSc.ScatterMode.FORWARD)
                tolerance = min(tolerance, polisher.solve_rtol)
            self.step1.set_tolerance(tolerance)
        self.step1.solve(self._b, x)
        self._nu = problem.apply_normal(x)
        # steps 2-3, with over-relaxation
        relaxed = s.alpha * self._nu + (1.0 - s.alpha) * p_in
        p, lam, defect = self.step(relaxed, lam_in, p_in, self._nu, r)
        self._Tz = np.concatenate([p, lam])
        self.multiplier = lam
        residuals = self.meter.measure(x, self.z, self._Tz, self._nu, defect)
        self.last_residual, self._res = residuals.fpr, residuals.res
        # safeguard: a proposal must lower the fixed-point residual (written as "not <"
        # so that a NaN residual is rejected too)
        self._rejected = (
            self.proposal != PLAIN
            and self.accepted is not None
            and not residuals.res < self.accepted[1]
        )
        if self.proposal == POLISHED and not self._rejected:
            self.polished_at = k
        self._record(k, residuals, REJECTED if self._rejected else self.proposal)
        return residuals

    def advance(self) -> None:
        """The state of the next iteration: T(z) or a proposal from it; collective."""
        m = self.m
        if self._rejected:
            assert self.accepted is not None  # a proposal is judged against it
            self.z, self.proposal = self.accepted[0].copy(), PLAIN  # the plain step instead
            return
        p_in, lam_in = self.z[:m], self.z[m:]
        self.accepted = (self._Tz, self._res)
        self.z, self.proposal = self._Tz, PLAIN
        if self.mixer is not None:
            candidate = self.mixer.update(np.concatenate([p_in, lam_in]), self._Tz)
            if candidate is not None:
                candidate[:m] = np.minimum(candidate[:m], self.problem.contact.gap)
                candidate[m:] = np.maximum(candidate[m:], 0.0)
                self.z, self.proposal = candidate, ANDERSON
        if self.polisher is not None and self.polished_at is None:
            budget = time.perf_counter() - self._started - self.polisher.time
            force = self.r * p_in - lam_in
            exact = self.polisher.attempt(self._nu, force, self.multiplier, budget)
            if exact is not None:
                self.z, self.proposal = np.concatenate(exact), POLISHED

    def tighten(self) -> bool:
        """Tighten an iterative step 1's inner tolerances; False if they cannot be."""
        return self.inexact is not None and self.inexact.tighten()

    def step1_info(self) -> Step1Info | None:
        """An iterative step 1's work during this solve (None for a direct one)."""
        if self.inexact is None:
            return None
        op = self.step1
        assert isinstance(op, IterativeOperator)
        before = self._work_before
        return Step1Info(
            krylov_iterations=op.iterations - before[0],
            solves=op.solves - before[1],
            unconverged=op.unconverged - before[2],
            last_rtol=op.rtol,
            tightened=self.inexact.tightened,
            time=op.solve_time - before[3],
        )

    def _record(self, k: int, residuals: IterationResiduals, what: int) -> None:
        """Keep one iteration's residuals in the history, and log them."""
        for key in HISTORY_KEYS:
            self.history[key].append(getattr(residuals, key))
        self.history["accelerated"].append(what)
        # every iteration at DEBUG; at INFO (progress) one line every PROGRESS_SECONDS
        now = time.perf_counter()
        level = logging.INFO if now >= self._next_progress else logging.DEBUG
        if level == logging.INFO:
            self._next_progress = now + PROGRESS_SECONDS
        line = (
            "ADMM %4d: fpr %.2e feas %.2e comp %.2e eq %.2e bal %.2e du %.2e dp %.2e active %d%s",
            k,
            residuals.fpr,
            residuals.feasibility,
            residuals.complementarity,
            residuals.equilibrium,
            residuals.force_balance,
            residuals.du,
            residuals.dp,
            residuals.active,
            " (proposal rejected)" if what == REJECTED else _NOTES[what],
        )
        if level == logging.INFO:
            progress(logger, *line)  # a terminal sees it even with logging unset
        else:
            logger.debug(*line)

    def destroy(self) -> None:
        """Free the work vectors (not u: it is the result's)."""
        self.meter.destroy()
        self._b0.destroy()
        self._b.destroy()
