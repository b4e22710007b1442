"""The ADMM iteration for unilateral contact (Koko 2019, Algorithm 2), and its acceleration.

With the lumped contact mass M, the contact directions N and the gap g (docs/design.md
§1–2), one
iteration maps the state z = (p, λ) to

    (A + r NᵀMN) u = f + NᵀM (r p − λ)              step 1: one solve (stored factors)
    ξ  = α N u + (1 − α) p                          over-relaxation (α = 1: the paper)
    p⁺ = min(ξ + λ / r, g)                          step 2: node-wise projection
    λ⁺ = max(λ + r (ξ − g), 0)                      step 3: multiplier update

A_r = A + r NᵀMN is fixed while r is: it is factorised once (MUMPS Cholesky by default)
and every iteration is one forward/backward substitution.

Two ideas cut the iteration count on the same factorisation:

* over-relaxation ``alpha`` ∈ (0, 2) (Eckstein–Bertsekas; OSQP's default is 1.6);
* Anderson acceleration (``anderson`` = memory k) of the map z ↦ T(z): from the last k
  residuals f = T(z) − z, a least-squares combination extrapolates the next state.
  It is safeguarded: an extrapolated state whose fixed-point residual is not smaller
  than that of the last accepted state is rejected and the plain step taken instead
  (the rejected evaluation still counts as an iteration). Extrapolated states are
  projected onto p ≤ g, λ ≥ 0.

Where the dense Schur complement S_C of A onto the contact dofs is at hand (2D with
a MUMPS factorisation: it also gives r*), *active-set polishing* (``polish``) finishes
the solve: after every iteration the guess 𝒜 = {λ⁺ > 0}, corrected by a few
primal-dual active-set steps on the dense m × m problem, gives the exact solution for
𝒜 (:mod:`admm_dolfinx.admm.polish_dense`). A state that satisfies every sign condition is
proposed like an Anderson step, and the next step-1 solve expands it to the
displacement, so a polished solve ends as soon as ADMM has found the contact set.

In 3D the default measures the penalty in the *surface metric* r(M + βL_Γ) instead
of r M (``penalty_metric``; :mod:`admm_dolfinx.operators.surface_metric`): step 1 factorises
A + rNᵀ(M + βL_Γ)N and steps 2–3 become a small QP on Γ_C, solved exactly (distributed).
The pencil that sets ADMM's rate is then well conditioned on every mesh, so the
iteration count no longer grows under refinement.

Stopping tests:

* ``"kkt"`` (default): the scaled fixed-point residual ‖T(z) − z‖_W / ‖T(z)‖_W and the
  relative KKT residuals of (u, λ⁺) - penetration, complementarity and equilibrium -
  are all ≤ ``rtol``. The equilibrium residual comes from the identity
  A u − f + NᵀMλ⁺ = NᵀM (r(p − Nu) + λ⁺ − λ) (in the surface metric
  M⁻¹R(p − Nu) replaces r(p − Nu)), so it costs no extra matrix product.
  W weighs p by M and λ by M/r², so both parts are displacements.
* ``"change"`` (the paper's): the relative changes of u and p⁺ are ≤ ``rtol``.

``mode="paper"`` is the paper's algorithm (a preset of :mod:`admm_dolfinx.admm.settings`):
α = 1, no acceleration, the relative-change test at the paper's tolerance. What the
solver chooses where a setting is automatic, and why, is its :attr:`ADMMSolver.plan`
(:mod:`admm_dolfinx.admm.plan`).

When the stopping test is met, the relative KKT residuals are recomputed
independently from (u, λ) (:mod:`admm_dolfinx.problem.kkt`): the solve has converged only if
they are ≤ ``kkt_tol`` too. The loop's own residuals rest on identities that assume
exact step-1 solves; the recomputed ones do not.

Failure policy: a solve that does not converge raises :class:`ADMMConvergenceError`,
with the partial result attached as ``err.result`` and its ``status`` saying why
(``"max_iter"``, ``"inaccurate"``: a met test with KKT residuals above ``kkt_tol``,
``"inexact_step1"``). A returned result is a converged one, except a stop asked for by
the callback, which says so (``status="callback"``, ``converged=False``).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from dolfinx import fem
from dolfinx.common import Timer
from mpi4py import MPI
from petsc4py import PETSc

from admm_dolfinx._logging import get_logger, speaking_for
from admm_dolfinx._mpi import agree, collective_call
from admm_dolfinx._threads import share_cores
from admm_dolfinx.admm.iteration import Iteration
from admm_dolfinx.admm.messages import failure_message, slow_convergence_warning
from admm_dolfinx.admm.plan import SolverPlan, make_plan
from admm_dolfinx.admm.polish_dense import ActiveSetPolish
from admm_dolfinx.admm.polish_sparse import SparsePolish
from admm_dolfinx.admm.residuals import IterationResiduals
from admm_dolfinx.admm.result import (
    ADMMConvergenceError,
    ADMMResult,
    PolishInfo,
    Step1Info,
    Timings,
    WarmStart,
)
from admm_dolfinx.admm.settings import ADMMSettings, check_penalty
from admm_dolfinx.admm.step2 import MassMetricStep, SurfaceMetricStep
from admm_dolfinx.operators.condensed import CondensedOperator
from admm_dolfinx.operators.penalised import IterativeOperator, PenalisedOperator
from admm_dolfinx.operators.surface_metric import SurfaceMetric
from admm_dolfinx.penalty.estimate import PenaltyEstimate, estimate_penalty
from admm_dolfinx.penalty.surface import (
    LAMBDA_MIN_RINGS,
    SurfacePenalty,
    estimate_surface_penalty,
)
from admm_dolfinx.problem.checks import check_finite
from admm_dolfinx.problem.contact_problem import ContactProblem
from admm_dolfinx.problem.contact_zone import contact_area, mean_pressure
from admm_dolfinx.problem.forces import contact_force
from admm_dolfinx.problem.kkt import KKTResiduals, compute_kkt_residuals
from admm_dolfinx.problem.penetration import obstacle_penetration
from admm_dolfinx.problem.resolution import assess_resolution

__all__ = ["ADMMConvergenceError", "ADMMResult", "ADMMSolver"]

logger = get_logger(__name__)


@dataclass(frozen=True)
class _LoopOutcome:
    """What the iteration hands to the result."""

    u: fem.Function
    multiplier: np.ndarray
    status: str
    iterations: int
    history: dict[str, list[float]]
    kkt: KKTResiduals
    polished_at: int | None
    iteration_time: float
    kkt_time: float
    #: ``time.perf_counter()`` when the solve started
    started: float
    step1: Step1Info | None


#: The settings :meth:`ADMMSolver.update_settings` may change between solves: they
#: change neither r, nor the factorisation, nor the plan.
ITERATION_SETTINGS = ("rtol", "kkt_tol", "max_iter", "alpha", "anderson", "stopping")


def _final_residual(result: ADMMResult) -> float | None:
    """The scaled fixed-point residual a result ended at (None if it recorded none).

    :class:`~admm_dolfinx.admm.inexact.InexactRule` ignores a NaN and an infinity.
    """
    fpr = result.history.get("fpr")
    return float(fpr[-1]) if fpr else None


class ADMMSolver:
    """ADMM for frictionless contact with a fixed penalty r and a reused factorisation.

    Args:
        problem: The contact problem.
        settings: An :class:`~admm_dolfinx.admm.settings.ADMMSettings` (the keyword
            options, if any, are applied on top of it).
        **options: The settings a user sets, by name (``penalty``, ``mode``, ``rtol``,
            ``max_iter``, ``polish``, ``step1``, ``petsc_options``,
            ``petsc_options_prefix``), and ``expert={...}`` for the algorithm's knobs
            (:data:`~admm_dolfinx.admm.settings.EXPERT_SETTINGS`): see
            :class:`~admm_dolfinx.admm.settings.ADMMSettings` for each, its default and
            its range.

    Raises:
        TypeError: For an unknown setting or a value of the wrong type.
        ValueError: For a value out of range, settings that conflict with each other
            or with the mode, or a choice the problem cannot take (see
            :func:`~admm_dolfinx.admm.plan.make_plan`).

    r* and the factorisation are computed here, once. They depend on A and NᵀMN only,
    so :meth:`solve` may be called again after
    :meth:`~admm_dolfinx.problem.contact_problem.ContactProblem.update_load` or
    :meth:`~admm_dolfinx.problem.contact_problem.ContactProblem.update_obstacle` (load
    steps), warm started from the previous result; where a moved obstacle turns the
    contact directions, the next solve recomputes them.

    The solver owns PETSc objects; call :meth:`destroy` (or use it as a context
    manager) to free them deterministically.
    """

    def __init__(
        self, problem: ContactProblem, settings: ADMMSettings | None = None, **options: Any
    ):
        if not isinstance(problem, ContactProblem):
            raise TypeError(f"problem must be a ContactProblem, got {type(problem).__name__}.")
        if settings is not None and not isinstance(settings, ADMMSettings):
            raise TypeError(f"settings must be ADMMSettings, got {type(settings).__name__}.")
        if problem.A is None:
            raise RuntimeError(
                "This ContactProblem has been destroyed (problem.destroy()); build a new "
                "ContactProblem for a new solver, and destroy a problem only after its "
                "solvers are done."
            )
        #: The validated settings (frozen), the same on every rank.
        self.settings: ADMMSettings = collective_call(
            problem.comm,
            lambda: (
                settings.replace(**options)
                if settings is not None
                else ADMMSettings.create(**options)
            ),
            "Validating the solver's settings",
        )
        self.settings.check_same_on_every_rank(problem.comm)
        self.problem = problem
        share_cores(problem.comm)  # ranks sharing a node: no oversubscribed BLAS threads
        self.operator: PenalisedOperator | CondensedOperator | None = None
        self.polisher: ActiveSetPolish | SparsePolish | None = None
        self._step: MassMetricStep | SurfaceMetricStep = MassMetricStep()
        self._metric: SurfaceMetric | None = None
        with speaking_for(problem.comm):
            self._build()

    def _build(self) -> None:
        """Plan, factorise and find r (collective); on a failure free what was built."""
        s, problem = self.settings, self.problem
        #: What the solver chose and why.
        self.plan: SolverPlan = make_plan(problem, s)
        plan, prefixes = self.plan, s.prefixes
        logger.info(
            "ADMM: %d dofs, %d contact nodes; %s",
            problem.V.dofmap.index_map.size_global * problem.V.dofmap.index_map_bs,
            problem.contact.num_global,
            plan.describe(),
        )
        #: The r* estimate when ``penalty="auto"`` (None otherwise).
        self.penalty_estimate: PenaltyEstimate | None = None
        #: β and r of the surface metric (None with the paper's metric r M).
        self.surface_penalty: SurfacePenalty | None = None
        self._operator_version = problem.operator_version
        private = None
        try:
            if plan.step1 == "condensed":
                self.operator = CondensedOperator(problem, prefixes["step1"], s.petsc_options)
            elif plan.step1 == "iterative":
                self.operator = IterativeOperator(problem, prefixes["step1"], plan.step1_options)
            else:
                self.operator = PenalisedOperator(problem, prefixes["step1"], plan.step1_options)
            schur_source = self.operator if plan.step1 == "condensed" else None
            if plan.private_schur:  # S_C for r* and polishing; freed once read
                private = CondensedOperator(problem, prefixes["schur"], None)
                schur_source = private
            if plan.polish == "dense":
                self.polisher = ActiveSetPolish.from_operator(
                    problem, schur_source, rounds=s.polish_rounds
                )
            elif plan.polish == "inverse":  # T from step 1's factors, set at each r
                self.polisher = ActiveSetPolish.from_factors(
                    problem, self.operator, rounds=s.polish_rounds
                )
            elif plan.polish == "sparse":
                self.polisher = SparsePolish(
                    problem,
                    prefixes["polish"],
                    plan.step1_options if plan.step1 == "iterative" else None,
                    kkt_tol=s.kkt_tol,
                )
            self._time_schur = private.timings["factorization"] if private else 0.0
            penalty = s.penalty  # a number unless "auto" (then r* or the surface r below)
            multigrid = None
            if (
                plan.penalty == "local"
                and isinstance(self.operator, IterativeOperator)
                and plan.step1_options.get("pc_type") == "gamg"
                # a floating body's A is singular: λ_max sets step 1's multigrid up on
                # A + r_a K instead
                and not problem.rigid_motions.floating
            ):
                # step 1's hierarchy, built on A now, preconditions r*'s λ_max too
                multigrid = self.operator.set_up_hierarchy()
                logger.info(
                    "step 1: multigrid hierarchy set up on A in %.3g s%s",
                    self.operator.timings["hierarchy"],
                    " (r*'s λ_max preconditions with it)" if multigrid is not None else "",
                )
            if plan.penalty != "given":
                # a condensed operator gives r* densely and serves the ADMM at r*; a
                # factorised one shares its symbolic analysis with r*'s factorisations;
                # a floating body's λ_max preconditions with step 1's multigrid of
                # A + r_a K on the multigrid path (never a factorisation of a body too
                # large for one; its Krylov–Schur fallback solves with step 1's CG)
                shared = schur_source or (
                    self.operator
                    if plan.step1 == "factorised"
                    or (
                        plan.step1 == "iterative"
                        and plan.penalty == "local"  # λ_max's solves only, λ_min is local
                        and problem.rigid_motions.floating
                    )
                    else None
                )
                assert plan.penalty_tol is not None  # resolved whenever r* is computed
                self.penalty_estimate = estimate_penalty(
                    problem,
                    tol=plan.penalty_tol,
                    method=plan.penalty,
                    operator=shared,
                    petsc_options_prefix=prefixes["penalty"],
                    multigrid=multigrid,
                    # the surface metric uses λ_min for β alone, which needs less
                    lambda_min_rings=LAMBDA_MIN_RINGS if plan.metric == "surface" else None,
                )
                penalty = self.penalty_estimate.r
            if plan.metric == "surface":
                operator = self.operator
                # make_plan refuses condensed=True with the surface metric
                assert isinstance(operator, PenalisedOperator)
                # the settings refuse a given penalty with the surface metric: r* is here
                assert self.penalty_estimate is not None
                self._metric = SurfaceMetric(problem)
                self.surface_penalty = estimate_surface_penalty(
                    problem,
                    self._metric,
                    self.penalty_estimate,
                    prefix=prefixes["surface"],
                )
                beta = self.surface_penalty.beta
                operator.use_penalty_matrix(self._metric.penalty_matrix(beta), "Nᵀ(M + βL_Γ)N")
                self._step = SurfaceMetricStep(self._metric, beta, prefixes["projection"])
                penalty = self.surface_penalty.r
            if isinstance(penalty, str):  # pragma: no cover - make_plan's invariant
                raise RuntimeError(f"internal: no penalty was found for penalty={penalty!r}.")
            self.set_penalty(penalty)
        except BaseException:
            self.destroy()  # collective: a failure here is raised on every rank
            raise
        finally:
            if private is not None:
                private.destroy()

    # ------------------------------------------------------------------ set-up
    @property
    def polish(self) -> bool:
        """Whether the solves polish (see :mod:`admm_dolfinx.admm.polish_dense`)."""
        return self.polisher is not None

    @property
    def _step1(self) -> PenalisedOperator | CondensedOperator:
        """The step-1 operator.

        Raises:
            RuntimeError: If the solver's construction did not get as far as building it.
        """
        if self.operator is None:
            raise RuntimeError("This ADMMSolver has no step-1 operator: its construction failed.")
        return self.operator

    @property
    def penalty(self) -> float:
        """The current penalty parameter r."""
        return self._step1.penalty

    def set_penalty(self, r: float) -> None:
        """Set r and make step 1 solve with A_r = A + r NᵀMN (factorised once per r).

        An ordinary operator redoes only the numeric factorisation (a new r keeps the
        sparsity pattern); a condensed one only a dense factorisation of S_C + r K_CC.

        Args:
            r: Penalty parameter, > 0.
        """
        r = check_penalty(r)
        self._step1.set_penalty(r)
        logger.info(
            "step 1: %s set up at r = %.6g in %.3g s",
            self.plan.step1,
            r,
            self._step1.timings["factorization"],
        )
        if self.polisher is not None:
            self.polisher.set_penalty(r)

    def update_settings(self, *, expert: Mapping[str, Any] | None = None, **changes: Any) -> None:
        """Change settings of the iteration between solves (OSQP's verb).

        Only :data:`ITERATION_SETTINGS` can change (``rtol`` and ``max_iter`` by name,
        the others in ``expert``): the rest set r, the factors or the plan (build a new
        solver for them).

        Raises:
            ValueError: For another setting, or an invalid value.
            TypeError: For a name spelled as it is not passed (see ``ADMMSettings``).
        """
        fixed = [name for name in (*changes, *(expert or {})) if name not in ITERATION_SETTINGS]
        if fixed:
            raise ValueError(
                f"update_settings changes {ITERATION_SETTINGS} only; {fixed} set r, the "
                "factorisation or the plan: build a new ADMMSolver with them."
            )
        settings = collective_call(
            self.problem.comm,
            lambda: self.settings.replace(expert=expert, **changes),
            "Validating the solver's settings",
        )
        settings.check_same_on_every_rank(self.problem.comm)
        self.settings = settings
        if isinstance(self.polisher, SparsePolish):  # its solves are tied to kkt_tol
            self.polisher.set_kkt_tol(settings.kkt_tol)

    @property
    def ksp(self) -> PETSc.KSP:
        """The step-1 KSP (factorised A + rNᵀMN, or A condensed onto Γ_C)."""
        return self._step1.ksp

    def summary(self) -> str:
        """The plan and the penalty, before (or without) a solve."""
        r = f"r = {self.penalty:.6g}"
        if self.surface_penalty is not None:
            r += f" in the surface metric (β = {self.surface_penalty.beta:.4g})"
        elif self.penalty_estimate is not None:
            r += f" (r* by the {self.plan.penalty} method)"
        return f"ADMMSolver: {self.plan.describe()}; {r}; settings: {self.settings.mode} mode"

    # ------------------------------------------------------------------ solve
    def _warm_state(self, previous: ADMMResult | WarmStart, u_start: PETSc.Vec) -> np.ndarray:
        """The state z⁰ = (min(N u, g), max(λ, 0)) of an earlier result; u copied to u_start."""
        problem = self.problem
        m = problem.contact.gap.size
        ok = (
            isinstance(previous, ADMMResult | WarmStart)
            and previous.u.function_space == problem.V
            and np.shape(previous.multiplier) == (m,)
        )
        if not problem.comm.allreduce(bool(ok), op=MPI.LAND):
            raise ValueError(
                "`warm_start` must be an ADMMResult (or a WarmStart) of this problem (same "
                "displacement space and contact nodes), e.g. the result of the previous load "
                "step."
            )
        check_finite(
            problem.comm,
            np.concatenate([previous.u.x.array, np.asarray(previous.multiplier)]),
            "The warm start (its displacement and contact pressure)",
            "Start from a converged result, or without warm_start.",
        )
        previous.u.x.petsc_vec.copy(u_start)
        p = np.minimum(problem.apply_normal(u_start), problem.contact.gap)
        return np.concatenate([p, np.maximum(previous.multiplier, 0.0)])

    def _prepare(self) -> None:
        """Bring the solver up to date with its problem before a solve; collective."""
        problem = self.problem
        if self.operator is None or self.operator.ksp is None:
            raise RuntimeError(
                "This ADMMSolver has been destroyed (destroy() or the end of its with "
                "block); create a new one."
            )
        if problem.A is None:
            raise RuntimeError(
                "The ContactProblem of this solver has been destroyed; destroy the "
                "problem only after its solvers are done."
            )
        if problem.sync_load():  # L's data or the Dirichlet values changed since
            logger.info("ADMM: the load data changed; reassembled the load")
        problem.check_obstacle_unchanged()
        if problem.operator_version != self._operator_version:
            # update_obstacle turned the contact directions: N, and with it r*, the
            # step-1 factorisation and the polisher's data, changed
            logger.info("ADMM: the contact directions changed; recomputing r and the factors")
            if self.settings.penalty != "auto":
                self.settings = self.settings.replace(penalty=self.penalty)
            self.destroy()
            self._step = MassMetricStep()
            self._build()

    def solve(
        self,
        callback: Callable[[int, PETSc.Vec, np.ndarray], bool] | None = None,
        *,
        warm_start: ADMMResult | WarmStart | None = None,
    ) -> ADMMResult:
        """Run ADMM from u⁰ = 0, λ⁰ = 0, p⁰ = min(0, g), or from an earlier result.

        Args:
            callback: Called after every iteration as ``callback(k, u, λ)`` on every
                rank (u is the displacement vector, λ the local multiplier). If it
                returns True on any rank, the iteration stops there and the result is
                returned with ``status="callback"`` and ``converged=False`` (benchmarks
                use this to stop at a given error against a reference). If it raises on
                any rank, every rank raises.
            warm_start: A result of this problem (e.g. the previous load step, after
                :meth:`ContactProblem.update_load` or ``update_obstacle``), or a
                :class:`~admm_dolfinx.admm.result.WarmStart` (u and λ from elsewhere, e.g.
                a coarser mesh): ADMM starts from its u, its λ and p⁰ = min(N u, g) with
                the current gap g.

        Returns:
            The converged result (or a callback's stop).

        Raises:
            ADMMConvergenceError: If the solve did not converge: the stopping test was
                not met within ``max_iter`` iterations, or it was met but the KKT
                residuals recomputed after the loop exceed ``kkt_tol`` (the partial
                result is ``err.result``; its ``status`` says which).
            ValueError: If the warm start, the load or the obstacle is not usable.
            RuntimeError: If a linear solve fails, or the solver or its problem has
                been destroyed.
        """
        with speaking_for(self.problem.comm):
            return self._solve(callback, warm_start)

    def _solve(
        self,
        callback: Callable[[int, PETSc.Vec, np.ndarray], bool] | None,
        warm_start: ADMMResult | WarmStart | None,
    ) -> ADMMResult:
        """:meth:`solve`'s work (its log on rank 0 of the problem's communicator)."""
        self._prepare()
        t_start = time.perf_counter()
        s, problem = self.settings, self.problem
        m, r = problem.num_contact_nodes, self.penalty
        logger.debug("ADMM: m = %d contact nodes, r = %.6g", m, r)
        u_start = problem.create_vector()
        try:
            z, previous_residual = self._start(warm_start, u_start)
            run = Iteration(self, z, u_start, previous_residual)
        finally:
            u_start.destroy()
        status, kkt = "max_iter", None
        try:
            with Timer("admm_dolfinx: iterations"):
                t0 = time.perf_counter()
                for k in range(1, s.max_iter + 1):
                    residuals = run.evaluate(k)
                    if residuals.meets(s.stopping, s.rtol):
                        status, kkt = self._confirm(run, k, residuals)
                        if status != "continue":
                            break
                        status, kkt = "max_iter", None  # unless a later iteration stops
                    if callback is not None and self._ask_callback(
                        callback, k, run.u.x.petsc_vec, run.multiplier
                    ):
                        status = "callback"
                        break
                    run.advance()
                t_iter = time.perf_counter() - t0
            run.u.x.scatter_forward()
            t0 = time.perf_counter()
            if kkt is None:
                kkt = compute_kkt_residuals(problem, run.u.x.petsc_vec, run.multiplier)
            t_kkt = time.perf_counter() - t0
        finally:
            run.destroy()
        result = self._result(
            _LoopOutcome(
                u=run.u,
                multiplier=run.multiplier,
                status=status,
                iterations=run.iterations,
                history=run.history,
                kkt=kkt,
                polished_at=run.polished_at,
                iteration_time=t_iter,
                kkt_time=t_kkt,
                started=t_start,
                step1=run.step1_info(),
            )
        )
        if result.warning:
            logger.warning("%s", result.warning, extra={"slow_convergence": True})
        if status not in ("converged", "callback"):
            raise ADMMConvergenceError(failure_message(result), result)
        logger.debug("%s", result.summary())
        return result

    def _start(
        self, warm_start: ADMMResult | WarmStart | None, u_start: PETSc.Vec
    ) -> tuple[np.ndarray, float | None]:
        """z⁰ = (p⁰, λ⁰), u⁰ into ``u_start``, and a warm start's last residual; collective.

        The residual (None from scratch) sets an iterative step 1's first tolerance.
        """
        gap = self.problem.contact.gap
        if warm_start is None:
            u_start.set(0.0)
            return np.concatenate([np.minimum(0.0, gap), np.zeros(gap.size)]), None
        z = self._warm_state(warm_start, u_start)
        # an iterative step 1 starts as tight as that solve ended: a loose first solve
        # would throw a warm start at a fixed point away (a WarmStart has no history)
        previous = _final_residual(warm_start) if isinstance(warm_start, ADMMResult) else None
        return z, previous

    def _confirm(
        self, run: Iteration, k: int, residuals: IterationResiduals
    ) -> tuple[str, KKTResiduals]:
        """A met stopping test, checked by KKT residuals recomputed from (u, λ); collective.

        Returns:
            The status (``"continue"``: iterate on) and the recomputed residuals.
        """
        kkt = compute_kkt_residuals(self.problem, run.u.x.petsc_vec, run.multiplier)
        status = self._verdict(kkt, residuals)
        if status == "inexact_step1" and run.tighten():
            logger.info(
                "ADMM %4d: test met, but the step-1 error shows in the recomputed KKT "
                "%.2e: tighter inner tolerances",
                k,
                kkt.max(),
            )
            status = "continue"
        if status == "continue":
            logger.info("ADMM %4d: test met, recomputed KKT %.2e: on", k, kkt.max())
        return status, kkt

    def _result(self, loop: _LoopOutcome) -> ADMMResult:
        """The typed result of a finished loop, with its outputs and warnings; collective."""
        problem, polisher = self.problem, self.polisher
        u, lam, history = loop.u, loop.multiplier, loop.history
        operator = self._step1
        penalty_time = (
            (self.penalty_estimate.time if self.penalty_estimate else 0.0)
            + (self.surface_penalty.time if self.surface_penalty else 0.0)
            + self._time_schur
        )
        phases = {
            "assembly": problem.timings.get("assembly", 0.0),
            "penalty": penalty_time,
            "operator": operator.timings["operator"]
            + (polisher.setup_time if polisher is not None else 0.0),
            "factorization": operator.timings["factorization"]
            + operator.timings.get("hierarchy", 0.0),
            "iterations": loop.iteration_time,
            "kkt": loop.kkt_time,
        }
        phases["total"] = (
            phases["assembly"]
            + phases["penalty"]
            + phases["operator"]
            + phases["factorization"]
            + time.perf_counter()
            - loop.started
        )
        polish = None
        if polisher is not None:
            polish = PolishInfo(
                kind=self.plan.polish,
                polished_at=loop.polished_at,
                attempts=polisher.attempts,
                rounds=polisher.rounds,
                skipped=polisher.skipped,
                time=polisher.time,
                krylov_iterations=(
                    polisher.krylov_iterations if isinstance(polisher, SparsePolish) else 0
                ),
            )
        converged = loop.status == "converged"
        penetration = obstacle_penetration(problem, u.x.array, lam, self.settings.kkt_tol)
        resolution = assess_resolution(problem, u, lam)
        result = ADMMResult(
            u=u,
            pressure=problem.pressure_function(lam),
            converged=converged,
            status=loop.status,
            iterations=loop.iterations,
            penalty=self.penalty,
            history=history,
            timings=Timings(**phases),
            kkt=loop.kkt,
            multiplier=lam,
            num_active=int(history["active"][-1]),
            num_contact_nodes=problem.contact.num_global,
            settings=self.settings,
            plan=self.plan,
            max_pressure=problem.global_norm(lam, np.inf),
            contact_force=contact_force(problem, lam),
            applied_load=problem.applied_load.copy(),
            contact_area=contact_area(problem, lam),
            mean_pressure=mean_pressure(problem, lam),
            problem=problem,
            penalty_estimate=self.penalty_estimate,
            surface_penalty=self.surface_penalty,
            polish=polish,
            projection=self._step.statistics(),
            step1=loop.step1,
            obstacle_penetration=penetration,
            resolution=resolution,
            warning="",
        )
        result.warning = " ".join(
            text
            for text in (
                slow_convergence_warning(result),
                penetration.message() if penetration is not None else "",
                resolution.message(),
            )
            if text
        )
        return result

    # ------------------------------------------------------------------ verdicts
    def _verdict(self, kkt: KKTResiduals, loop: IterationResiduals) -> str:
        """What a met stopping test means, given the KKT residuals recomputed from (u, λ).

        Args:
            kkt: The residuals recomputed from (u, λ).
            loop: The loop's own residuals of the same iteration.

        Returns:
            ``"converged"``; ``"continue"`` (the loop's residuals and the recomputed
            ones differ by their definitions only: iterate on); ``"inexact_step1"``
            (the equilibrium identity of the loop is off: the step-1 solves are not
            exact); ``"inaccurate"`` (the change test stopped a stagnated iteration).
        """
        tol = self.settings.kkt_tol
        if kkt.max() <= tol:
            return "converged"
        if self.plan.step1 == "iterative" and self.settings.stopping == "kkt":
            # the loop met the test, so with exact solves the recomputed residuals
            # would too: what is left is the step-1 error
            return "inexact_step1"
        if kkt.equilibrium > 10.0 * max(tol, loop.equilibrium) or (
            kkt.force_balance > 10.0 * max(tol, loop.force_balance)
        ):
            return "inexact_step1"
        return "inaccurate" if self.settings.stopping == "change" else "continue"

    def _ask_callback(self, callback, k: int, x: PETSc.Vec, lam: np.ndarray) -> bool:
        """The user's callback on every rank; True if any rank asks to stop; collective."""
        answer = collective_call(self.problem.comm, lambda: callback(k, x, lam), "The callback")
        stop, unanimous = agree(self.problem.comm, bool(answer))
        if stop and not unanimous:
            logger.warning("ADMM: the callback asked to stop on some ranks only; stopping.")
        return stop

    # ------------------------------------------------------------------ lifetime
    def destroy(self) -> None:
        """Free the KSP, the step-1 operator, the polisher and the surface metric; collective."""
        for name in ("operator", "polisher", "_step", "_metric"):
            obj = getattr(self, name, None)
            if obj is not None:
                obj.destroy()
        self.polisher = self._metric = None

    def __enter__(self) -> ADMMSolver:
        return self

    def __exit__(self, *exc) -> None:
        self.destroy()
