"""The ADMM iteration for unilateral contact (Koko 2019, Algorithm 2), and its acceleration.

With the lumped contact mass M, nodal normals N and the gap g (design.md §1–2), one
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
of r M (``penalty_metric``; :mod:`admm_dolfinx.linalg.surface_metric`): step 1 factorises
A + rNᵀ(M + βL_Γ)N and steps 2–3 become a small QP on Γ_C, solved exactly on rank 0.
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

``mode="paper"`` is the paper's algorithm: α = 1, no acceleration, the relative-change
test at ``rtol = 1e-5`` (which reproduces its iteration counts).

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

import math
import numbers
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt
from dolfinx import fem
from dolfinx.common import Timer
from mpi4py import MPI
from petsc4py import PETSc

from admm_dolfinx._logging import get_logger
from admm_dolfinx._mpi import agree, collective_call
from admm_dolfinx.admm.anderson import AndersonMixer, weighted_norm
from admm_dolfinx.admm.polish_dense import ActiveSetPolish
from admm_dolfinx.admm.polish_sparse import SparsePolish
from admm_dolfinx.admm.surface_projection import SurfaceProjection
from admm_dolfinx.linalg.condensed import CondensedOperator, condensed_factor_applies
from admm_dolfinx.linalg.operators import PenalisedOperator
from admm_dolfinx.linalg.petsc import is_factorisation, unique_prefix
from admm_dolfinx.linalg.surface_metric import SurfaceMetric
from admm_dolfinx.penalty.estimate import DEFAULT_PENALTY_TOL, PenaltyEstimate, estimate_penalty
from admm_dolfinx.penalty.surface import SurfacePenalty, estimate_surface_penalty
from admm_dolfinx.problem.checks import check_finite
from admm_dolfinx.problem.contact_problem import ContactProblem
from admm_dolfinx.problem.kkt import KKTResiduals, _ratio, compute_kkt_residuals, gap_residuals

__all__ = ["ADMMConvergenceError", "ADMMResult", "ADMMSolver"]

logger = get_logger(__name__)

#: Tolerance of the paper's relative-change test. With it, Example 1 needs the
#: iteration counts of the paper's Table 1 (19 at r̄ and 35 at r* for h = 1/8, against
#: our 19 and 34), so it is taken to be the paper's tolerance.
PAPER_RTOL = 1e-5
#: Default tolerance of the KKT / fixed-point-residual test.
DEFAULT_RTOL = 1e-6
#: Default ``kkt_tol`` with the relative-change test: that test bounds the changes of
#: u and p, not the residuals, which it leaves larger where ADMM contracts slowly (a
#: floating body at r*, a penalty at the edge of the paper's sampling range); a
#: stagnated iteration (an r orders of magnitude off) is far above it.
CHANGE_TEST_KKT_TOL = 1e-2
#: Defaults of the accelerated mode, chosen by ``benchmarks/acceleration.py``.
DEFAULT_ALPHA = 1.6
DEFAULT_ANDERSON = 5

_STOPPING = ("kkt", "change")
_METRICS = ("auto", "mass", "surface")
#: ``history["accelerated"]`` codes: what the evaluated state was.
_REJECTED, _PLAIN, _ANDERSON, _POLISHED = -1, 0, 1, 2
_NOTES = {_PLAIN: "", _ANDERSON: " (Anderson)", _POLISHED: " (polished)"}
#: A solve that needs this many iterations or more says so in ``result.extra["warning"]``.
SLOW_ITERATIONS = 300


@dataclass
class ADMMResult:
    """Outcome of :meth:`ADMMSolver.solve`.

    Attributes:
        u: Displacement, a Function on the problem's space.
        pressure: Contact pressure λ ≥ 0 as a P1 scalar Function, zero off Γ_C.
        converged: Whether the solve converged: the stopping test was met *and* the
            relative KKT residuals recomputed from (u, λ) after the loop (:attr:`kkt`)
            are at most the solver's ``kkt_tol``. True for every returned result
            except a callback stop.
        status: ``"converged"``; ``"callback"`` (the callback asked to stop: returned
            with ``converged=False``); on the result attached to an
            :class:`ADMMConvergenceError`: ``"max_iter"`` (the test was not met),
            ``"inaccurate"`` (the test was met but the recomputed KKT residuals exceed
            ``kkt_tol``: the iteration stagnated) or ``"inexact_step1"`` (the step-1
            solves are not exact enough for the loop's residual identity).
        iterations: Number of ADMM iterations (= step-1 solves, rejected Anderson
            steps included).
        penalty: The penalty parameter r that was used.
        history: Per-iteration lists: ``du``, ``dp`` (relative changes of u and p),
            ``fpr`` (scaled fixed-point residual), ``feasibility``, ``complementarity``,
            ``equilibrium`` (relative KKT residuals), ``active`` (global number of
            nodes with λ > 0) and ``accelerated`` (what the evaluated state was: 0 a
            plain step, 1 an accepted Anderson extrapolation, 2 an accepted polished
            state, −1 a rejected proposal).
        timings: Wall-clock seconds: ``assembly`` (problem operators), ``penalty``
            (r*), ``operator`` (A + rK, and the dense compliance of Γ_C when
            polishing), ``factorization``, ``iterations``, ``kkt``, ``total``.
        kkt: Relative KKT residuals of (u, λ), computed independently after the loop.
        multiplier: λ at the owned contact nodes (local array).
        num_active: Global number of contact nodes with λ > 0.
        num_contact_nodes: Global number m of contact nodes.
        settings: The solver settings (mode, alpha, anderson, stopping, rtol, kkt_tol,
            max_iter, polish, penalty_metric).
        extra: ``max_pressure``, the ``penalty_estimate`` (as a dict) if any,
            ``polish`` (None when off; else ``polished_at``, the iteration that
            evaluated the polished state or None, ``attempts``, ``rounds`` (dense
            solves), ``skipped`` (attempts skipped because polishing had taken longer
            than the rest of the iterations) and ``time``, seconds within the
            iterations), and a ``warning``
            (non-empty when the solve was slow: ≥ 300 iterations, with the observed
            contraction rate and the likely cause).
    """

    u: fem.Function
    pressure: fem.Function
    converged: bool
    status: str
    iterations: int
    penalty: float
    history: dict[str, list[float]]
    timings: dict[str, float]
    kkt: KKTResiduals
    multiplier: npt.NDArray[np.float64]
    num_active: int
    num_contact_nodes: int
    settings: dict[str, Any] = field(default_factory=dict)
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def polished(self) -> bool:
        """Whether the solve ended from a polished (exact active-set) state."""
        return bool((self.extra.get("polish") or {}).get("polished_at"))

    def summary(self) -> str:
        """A short human-readable report (what the demos print)."""
        status = {
            "converged": "converged",
            "callback": "stopped by the callback (not converged)",
            "max_iter": "NOT CONVERGED (iteration limit)",
            "inaccurate": "NOT CONVERGED (stagnated: KKT residuals above tolerance)",
            "inexact_step1": "NOT CONVERGED (inexact step-1 solves)",
        }.get(self.status, self.status)
        k = self.kkt
        t = self.timings
        est = self.extra.get("penalty_estimate")
        surface = self.extra.get("surface_penalty")
        how = (
            f" (r* from λ_min {est['lambda_min']:.4g}, λ_max {est['lambda_max']:.4g}, "
            f"{est['solves']} solves)"
            if est
            else ""
        )
        if surface:
            how = (
                f" in the surface metric r(M + βL_Γ), β = {surface['beta']:.4g} "
                f"(from r* {est['r']:.6g}: λ_min {est['lambda_min']:.4g}, λ_max "
                f"{est['lambda_max']:.4g}; μ_max {surface['mu_max']:.4g})"
            )
        s = self.settings
        lines = [
            f"ADMM {status} in {self.iterations} iterations, r = {self.penalty:.6g}{how}",
            f"  {s.get('mode', '')} mode: alpha {s.get('alpha')}, Anderson memory "
            f"{s.get('anderson')}, polish {'on' if s.get('polish') else 'off'}, stopping "
            f"'{s.get('stopping')}' at rtol {s.get('rtol'):g} (KKT checked at "
            f"{s.get('kkt_tol'):g})",
            f"  contact nodes m = {self.num_contact_nodes}, active (λ > 0) = {self.num_active}",
            f"  max pressure = {self.extra.get('max_pressure', float('nan')):.6g}",
            "  KKT residuals (relative): "
            f"feasibility {k.primal_feasibility:.2e}, complementarity "
            f"{k.complementarity:.2e}, equilibrium {k.equilibrium:.2e}",
            "  time [s]: " + ", ".join(f"{name} {value:.3f}" for name, value in t.items()),
        ]
        polish = self.extra.get("polish")
        if polish:
            at = polish["polished_at"]
            lines.append(
                f"  polish: {'exact state from iteration ' + str(at) if at else 'not used'}"
                f" ({polish['attempts']} attempts, {polish['rounds']} active-set rounds, "
                f"{polish['time']:.3f} s)"
            )
        if self.extra.get("warning"):
            lines.append(f"  WARNING: {self.extra['warning']}")
        return "\n".join(lines)


class ADMMConvergenceError(RuntimeError):
    """Raised when ADMM does not meet its stopping test within ``max_iter`` iterations.

    Attributes:
        result: The (unconverged) result at the last iterate, ``converged=False``.
    """

    def __init__(self, message: str, result: ADMMResult):
        super().__init__(message)
        self.result = result


def _real(name: str, value: Any) -> float:
    """``value`` as a float if it is a real number (NumPy scalars included), else raise."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise TypeError(f"{name} must be a real number, got {value!r}.")
    return float(value)


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


class ADMMSolver:
    """ADMM for frictionless contact with a fixed penalty r and a reused factorisation.

    Args:
        problem: The contact problem.
        penalty: Penalty parameter r > 0, or ``"auto"`` for r* = 1/sqrt(λ_min λ_max)
            from :func:`~admm_dolfinx.penalty.estimate.estimate_penalty` (the default).
        mode: ``"accelerated"`` (default: ``alpha``, ``anderson`` and ``stopping`` as
            given) or ``"paper"`` (α = 1, no acceleration, relative-change test).
        rtol: Tolerance of the stopping test; default 1e-6, or 1e-5 in paper mode.
        max_iter: Maximum number of iterations (≥ 1).
        alpha: Over-relaxation α ∈ (0, 2); 1 is plain ADMM.
        anderson: Anderson memory k ≥ 0; 0 switches acceleration off.
        stopping: ``"kkt"`` or ``"change"`` (see the module docstring).
        penalty_tol: Eigenvalue tolerance of the iterative r* estimate (``penalty="auto"``
            in 3D; the 2D one is exact).
        petsc_options: Options of the step-1 solver, overriding MUMPS Cholesky
            (``{"pc_type": "lu"}``, ``{"mat_mumps_icntl_14": 50}``, ...).
        petsc_options_prefix: Options prefix of the step-1 KSP; a unique one by default.
        condensed: Solve step 1 with one factorisation of A condensed onto the contact
            dofs (:class:`~admm_dolfinx.linalg.condensed.CondensedOperator`), where a new r
            costs a dense factorisation of size ≈ m instead of a sparse one. ``None``
            (default): when ``penalty="auto"`` in 2D on one process with a MUMPS
            factorisation, which then also gives r* exactly; ``True``: always (2D
            sizes of Γ_C, one process, MUMPS; e.g. for sweeps over r); ``False``: never.
        polish: Active-set polishing from the dense Schur complement S_C (see the
            module docstring). ``None`` (default): wherever S_C is computed anyway, i.e.
            with ``penalty="auto"`` in 2D with a MUMPS factorisation (on any number of
            processes: under MPI a private condensed factorisation serves r* and the
            polisher), or with ``condensed=True``; ``True``: always (computing S_C if
            need be: in 3D it is dense on a surface, which makes the factorisation
            1.4–1.6× dearer: on one process 3–5× faster than the 3D default up to
            557 contact nodes, slower from 2137 on, and slower under MPI, where it
            is a second factorisation; ``benchmarks/polish_3d.py``); ``False``:
            never. Paper mode never polishes.
        penalty_metric: The norm of the penalty term (:mod:`admm_dolfinx.linalg.surface_metric`):
            ``"mass"``, the paper's r M; ``"surface"``, r (M + βL_Γ) with L_Γ the
            Laplace–Beltrami stiffness of Γ_C, which makes the iteration count
            independent of the mesh (3D, ``penalty="auto"``: β and r are chosen by
            :func:`~admm_dolfinx.penalty.surface.estimate_surface_penalty`, not in
            paper mode, not with polishing); ``"auto"`` (default): ``"surface"``
            where it applies, i.e. in 3D with ``penalty="auto"``, the accelerated
            mode and no polishing, else ``"mass"``.
        kkt_tol: Tolerance of the final check: after the stopping test is met, the
            relative KKT residuals of (u, λ) are recomputed independently
            (:func:`~admm_dolfinx.problem.kkt.compute_kkt_residuals`), and the solve has
            converged only if they are all ≤ ``kkt_tol``. Default: ``rtol`` with the
            ``"kkt"`` test (which it then confirms); with the ``"change"`` test, whose
            relative changes do not bound the residuals, ``1e-2``.

    Raises:
        ValueError: For r ≤ 0, NaN or inf, ``rtol`` ≤ 0, ``max_iter`` < 1, α outside
            (0, 2), a negative Anderson memory, ``penalty_tol`` outside (0, 1), or an
            unknown mode or stopping test;
            for ``condensed=True`` under MPI or without a MUMPS factorisation, and
            ``polish=True`` without a MUMPS factorisation;
            ``penalty_metric="surface"`` in 2D, in paper mode, with a given penalty or
            with ``polish=True``.

    r* and the factorisation are computed here, once. They depend on A and NᵀMN only,
    so :meth:`solve` may be called again after
    :meth:`~admm_dolfinx.problem.contact_problem.ContactProblem.update_load` or
    :meth:`~admm_dolfinx.problem.contact_problem.ContactProblem.update_obstacle` (load steps), warm
    started from the previous result.

    The solver owns PETSc objects; call :meth:`destroy` (or use it as a context
    manager) to free them deterministically.
    """

    def __init__(
        self,
        problem: ContactProblem,
        *,
        penalty: float | str = "auto",
        mode: str = "accelerated",
        rtol: float | None = None,
        max_iter: int = 1000,
        alpha: float = DEFAULT_ALPHA,
        anderson: int = DEFAULT_ANDERSON,
        stopping: str = "kkt",
        penalty_tol: float = DEFAULT_PENALTY_TOL,
        petsc_options: Mapping[str, Any] | None = None,
        petsc_options_prefix: str | None = None,
        condensed: bool | None = None,
        polish: bool | None = None,
        penalty_metric: str = "auto",
        kkt_tol: float | None = None,
    ):
        if not isinstance(problem, ContactProblem):
            raise TypeError(f"problem must be a ContactProblem, got {type(problem).__name__}.")
        # what a rebuild needs when the problem's N changes (a moved curved obstacle)
        self._arguments = {
            k: v for k, v in locals().items() if k not in ("self", "problem", "__class__")
        }
        self._operator_version = problem.operator_version
        if mode == "paper":
            alpha, anderson, stopping, polish = 1.0, 0, "change", False
            rtol = PAPER_RTOL if rtol is None else rtol
        elif mode != "accelerated":
            raise ValueError(f"mode must be 'accelerated' or 'paper', got {mode!r}.")
        rtol = DEFAULT_RTOL if rtol is None else _real("rtol", rtol)
        if not (math.isfinite(rtol) and rtol > 0.0):
            raise ValueError(f"rtol must be a positive finite number, got {rtol!r}.")
        if isinstance(max_iter, bool) or not isinstance(max_iter, int | np.integer):
            raise TypeError(f"max_iter must be an int, got {max_iter!r}.")
        if max_iter < 1:
            raise ValueError(f"max_iter must be at least 1, got {max_iter}.")
        alpha = _real("alpha", alpha)
        if not 0.0 < alpha < 2.0:
            raise ValueError(f"alpha (over-relaxation) must lie in (0, 2), got {alpha}.")
        if isinstance(anderson, bool) or not isinstance(anderson, int | np.integer):
            raise TypeError(f"anderson (memory) must be an int, got {anderson!r}.")
        if anderson < 0:
            raise ValueError(f"anderson (memory) must be ≥ 0 (0: off), got {anderson}.")
        penalty_tol = _real("penalty_tol", penalty_tol)
        if not 0.0 < penalty_tol < 1.0:
            raise ValueError(f"penalty_tol must lie in (0, 1), got {penalty_tol!r}.")
        if stopping not in _STOPPING:
            raise ValueError(f"stopping must be one of {_STOPPING}, got {stopping!r}.")
        if kkt_tol is None:
            kkt_tol = rtol if stopping == "kkt" else CHANGE_TEST_KKT_TOL
        kkt_tol = _real("kkt_tol", kkt_tol)
        if not (math.isfinite(kkt_tol) and kkt_tol > 0.0):
            raise ValueError(f"kkt_tol must be a positive finite number, got {kkt_tol!r}.")
        if stopping == "kkt" and kkt_tol < rtol:
            raise ValueError(
                f"kkt_tol = {kkt_tol:g} is below rtol = {rtol:g}: with the 'kkt' stopping "
                "test the loop stops at rtol, so the final check could never pass. Lower "
                "rtol instead."
            )
        if penalty_metric not in _METRICS:
            raise ValueError(f"penalty_metric must be one of {_METRICS}, got {penalty_metric!r}.")
        for name, value in (("condensed", condensed), ("polish", polish)):
            if value is not None and not isinstance(value, bool):
                raise TypeError(f"{name} must be None (automatic), True or False, got {value!r}.")
        auto = isinstance(penalty, str) and penalty == "auto"
        if not auto:
            penalty = _check_penalty(penalty)
        if penalty_metric == "surface":
            reasons = [
                (problem.gdim != 3, "is for 3D bodies (a contact surface); this one is 2D"),
                (not auto, "chooses r and β itself: pass penalty='auto'"),
                (mode == "paper", "is not the paper's algorithm: use mode='accelerated'"),
                (polish is True, "and polish=True exclude each other"),
            ]
            for failed, reason in reasons:
                if failed:
                    raise ValueError(
                        f"penalty_metric='surface' {reason} (or pass penalty_metric='mass')."
                    )
        self.problem = problem
        self.mode = mode
        self.rtol = rtol
        self.max_iter = int(max_iter)
        self.alpha = alpha
        self.anderson = int(anderson)
        self.stopping = stopping
        self.kkt_tol = kkt_tol
        self._petsc_options = dict(petsc_options or {})
        self.prefix = petsc_options_prefix or unique_prefix("admm_")
        # S_C, the Schur complement of A onto the contact dofs, gives r* exactly (2D)
        # and polishing; solving with it (condensed) needs one process
        explicit = condensed is True or polish is True
        schur_possible = condensed_factor_applies(problem, petsc_options, any_dimension=explicit)
        serial = problem.comm.size == 1
        if condensed is True and not (serial and schur_possible):
            raise ValueError(
                "condensed=True needs one process and a MUMPS factorisation (PETSc "
                "solves with a Schur complement serially only); pass condensed=None."
            )
        if polish is True and not schur_possible:
            raise ValueError(
                "polish=True needs the Schur complement of A onto the contact dofs, "
                "from a MUMPS factorisation (ksp_type preonly, pc_type cholesky or lu); "
                f"got petsc_options={dict(petsc_options or {})}. Pass polish=None."
            )
        if condensed is None:
            condensed = serial and schur_possible and (auto or polish is True)
        #: Active-set polishing (None when off).
        self.polisher: ActiveSetPolish | SparsePolish | None = None
        #: The r* estimate when ``penalty="auto"`` (None otherwise).
        self.penalty_estimate: PenaltyEstimate | None = None
        #: β and r of the surface metric (None with the paper's metric r M).
        self.surface_penalty: SurfacePenalty | None = None
        self._metric: SurfaceMetric | None = None
        self._projection: SurfaceProjection | None = None
        self.operator: PenalisedOperator | CondensedOperator | None = None
        # The inner factorisations of r* (layers, the body at r_a) take the step-1
        # options only if those describe a factorisation too (MUMPS's memory options);
        # an iterative step-1 solver's options are not theirs.
        factor_opts = dict(petsc_options or {}) if is_factorisation(petsc_options) else None
        private = None
        try:
            operator_class = CondensedOperator if condensed else PenalisedOperator
            self.operator = operator_class(problem, self.prefix, petsc_options)
            # where the step-1 operator is not condensed, a private condensed
            # factorisation serves r* (2D) and polishing, and is freed once S_C is read
            schur_source = self.operator if condensed else None
            if schur_source is None and schur_possible and polish is not False and (auto or polish):
                private = CondensedOperator(problem, self.prefix + "schur_", petsc_options)
                schur_source = private
            if schur_source is not None and polish is not False:
                self.polisher = ActiveSetPolish.from_operator(problem, schur_source)
            elif (
                polish is not False
                and (auto or polish)
                and problem.gdim == 2
                and factor_opts is not None
            ):
                # 2D contact zones too large for the dense S_C: the same polishing with
                # sparse factorisations of the body
                self.polisher = SparsePolish(problem, self.prefix + "polish_", factor_opts)
            surface = penalty_metric == "surface" or (
                penalty_metric == "auto"
                and problem.gdim == 3
                and auto
                and mode == "accelerated"
                and self.polisher is None
            )
            self._time_schur = private.timings["factorization"] if private else 0.0
            if auto:
                # r* gets this solver's own operator: a condensed one gives r* densely
                # and serves the ADMM at r* with no new sparse factorisation. Otherwise,
                # at the default tolerance r* factorises nothing of the whole body; where
                # it does (tight tolerance, floating body: at an auxiliary r_a), the
                # factorisation at r* below reuses its symbolic analysis.
                shared = schur_source or (self.operator if factor_opts is not None else None)
                self.penalty_estimate = estimate_penalty(
                    problem,
                    tol=penalty_tol,
                    operator=shared,
                    petsc_options=factor_opts,
                    petsc_options_prefix=self.prefix + "penalty_",
                )
                penalty = self.penalty_estimate.r
            if surface:
                self._metric = SurfaceMetric(problem)
                self.surface_penalty = estimate_surface_penalty(
                    problem,
                    self._metric,
                    self.penalty_estimate,
                    prefix=self.prefix + "surface_",
                    petsc_options=factor_opts,
                )
                beta = self.surface_penalty.beta
                self.operator.use_penalty_matrix(self._metric.penalty_matrix(beta), "Nᵀ(M + βL_Γ)N")
                self._projection = SurfaceProjection(self._metric, beta)
                penalty = self.surface_penalty.r
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
    def penalty(self) -> float:
        """The current penalty parameter r."""
        return self.operator.penalty

    def set_penalty(self, r: float) -> None:
        """Set r and make step 1 solve with A_r = A + r NᵀMN (factorised once per r).

        An ordinary operator redoes only the numeric factorisation (a new r keeps the
        sparsity pattern); a condensed one only a dense factorisation of S_C + r K_CC.

        Args:
            r: Penalty parameter, > 0.
        """
        r = _check_penalty(r)
        self.operator.set_penalty(r)
        if self.polisher is not None:
            self.polisher.set_penalty(r)

    @property
    def ksp(self) -> PETSc.KSP:
        """The step-1 KSP (factorised A + rNᵀMN, or A condensed onto Γ_C)."""
        return self.operator.ksp

    @property
    def settings(self) -> dict[str, Any]:
        """The settings that define the iteration."""
        return {
            "mode": self.mode,
            "alpha": self.alpha,
            "anderson": self.anderson,
            "stopping": self.stopping,
            "rtol": self.rtol,
            "kkt_tol": self.kkt_tol,
            "max_iter": self.max_iter,
            "polish": self.polish,
            "penalty_metric": "mass" if self._projection is None else "surface",
        }

    # ------------------------------------------------------------------ solve
    def _warm_state(self, previous: ADMMResult, u_start: PETSc.Vec) -> np.ndarray:
        """The state z⁰ = (min(N u, g), max(λ, 0)) of an earlier result; u copied to u_start."""
        problem = self.problem
        m = problem.contact.gap.size
        ok = (
            isinstance(previous, ADMMResult)
            and previous.u.function_space == problem.V
            and np.shape(previous.multiplier) == (m,)
        )
        if not problem.comm.allreduce(bool(ok), op=MPI.LAND):
            raise ValueError(
                "`warm_start` must be an ADMMResult of this problem (same displacement "
                "space and contact nodes), e.g. the result of the previous load step."
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

    def solve(
        self,
        callback: Callable[[int, PETSc.Vec, np.ndarray], bool] | None = None,
        *,
        warm_start: ADMMResult | None = None,
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
                :meth:`ContactProblem.update_load` or ``update_obstacle``): ADMM starts
                from its u, its λ and p⁰ = min(N u, g) with the current gap g.

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
        problem = self.problem
        if self.operator.ksp is None:
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
            arguments = dict(self._arguments)
            if self.penalty_estimate is None and self.surface_penalty is None:
                arguments["penalty"] = self.penalty
            self.destroy()
            self.__init__(problem, **arguments)
        c = problem.contact
        r, alpha = self.penalty, self.alpha
        g = c.gap
        m = g.size
        t_start = time.perf_counter()
        mass = c.mass
        # |NᵀM e_j| on the free dofs: turns nodal values into the equilibrium residual
        force = np.linalg.norm(c.free_normals, axis=1) * mass
        # W-norm of z = (p, λ): p weighted by M, λ by M/r² (both in displacement units)
        weights = np.concatenate([mass, mass / r**2])

        def wnorm(vec):
            return weighted_norm(vec, weights, problem.comm)

        mixer = AndersonMixer(self.anderson, weights, problem.comm) if self.anderson else None
        load_norm = problem.load_norm

        u = fem.Function(problem.V, name="displacement")
        x = u.x.petsc_vec
        x_old = problem.create_vector()
        b0 = problem.create_vector()
        b = problem.create_vector()
        problem.assemble_rhs(r, b0)
        projection = self._projection
        if projection is not None:  # steps 2-3 in the metric r(M + βL_Γ)
            projection.reset(g)
            if self._metric.dirichlet_lift(b):
                b0.axpy(r * projection.beta, b)

        if warm_start is None:
            x_old.set(0.0)
            z = np.concatenate([np.minimum(0.0, g), np.zeros(m)])  # state (p, λ)
        else:
            z = self._warm_state(warm_start, x_old)
        p_prev = z[:m].copy()
        keys = (
            "du",
            "dp",
            "fpr",
            "feasibility",
            "complementarity",
            "equilibrium",
            "active",
            "accelerated",
        )
        history: dict[str, list[float]] = {key: [] for key in keys}
        status = "max_iter"
        kkt: KKTResiduals | None = None
        iterations = 0
        accepted: tuple[np.ndarray, float] | None = None  # (T(z), residual) last accepted
        proposal = _PLAIN  # what z is: a plain step, or an Anderson or polished proposal
        polisher = self.polisher
        if polisher is not None:
            polisher.reset()
        polished_at = None
        lam = z[m:]
        logger.info("ADMM: m = %d contact nodes, r = %.6g, %s", c.num_global, r, self.settings)
        try:
            with Timer("admm_dolfinx: iterations"):
                t0 = time.perf_counter()
                for k in range(1, self.max_iter + 1):
                    iterations = k
                    p_in, lam_in = z[:m], z[m:]
                    # step 1: (A + rK) u = f + NᵀM(r p − λ)
                    b0.copy(b)
                    problem.add_normal_force(b, r * p_in - lam_in)
                    if projection is not None:  # Nᵀ R p = r NᵀM p + r β Nᵀ L_Γ p
                        self._metric.add_surface_force(b, p_in, r * projection.beta)
                    self.operator.solve(b, x)
                    nu = problem.apply_normal(x)
                    # steps 2-3 with over-relaxation
                    xi = alpha * nu + (1.0 - alpha) * p_in
                    if projection is None:
                        with np.errstate(invalid="ignore"):
                            p = np.minimum(xi + lam_in / r, g)
                            lam = np.maximum(lam_in + r * (xi - g), 0.0)
                        # A u − f + NᵀMλ⁺ = NᵀM d at the contact nodes (Dirichlet rows aside)
                        d = r * (p_in - nu) + (lam - lam_in)
                    else:
                        p, lam, d = projection(xi, lam_in, p_in, nu, r)
                    Tz = np.concatenate([p, lam])

                    # residuals of (u, λ⁺) and of the fixed-point map
                    res = wnorm(Tz - z)
                    fpr = _ratio(res, wnorm(Tz))
                    x_old.axpy(-1.0, x)
                    du = _ratio(x_old.norm(), x.norm())
                    x.copy(x_old)
                    dp = _ratio(problem.global_norm(p - p_prev), problem.global_norm(p))
                    p_prev = p
                    u_scale = x.norm(PETSc.NormType.NORM_INFINITY)
                    feas, comp = gap_residuals(problem, nu, lam, u_scale)
                    eq = _ratio(
                        problem.global_norm(force * d),
                        max(load_norm, problem.global_norm(force * lam)),
                    )
                    active = int(problem.comm.allreduce(int(np.count_nonzero(lam > 0.0))))

                    # safeguard: an extrapolated state must lower the fixed-point residual
                    # (written as "not <" so that a NaN residual is rejected too)
                    rejected = proposal != _PLAIN and accepted is not None and not res < accepted[1]
                    if proposal == _POLISHED and not rejected:
                        polished_at = k
                    for key, val in zip(
                        keys,
                        (du, dp, fpr, feas, comp, eq, active, _REJECTED if rejected else proposal),
                        strict=True,
                    ):
                        history[key].append(val)
                    logger.info(
                        "ADMM %4d: fpr %.2e feas %.2e comp %.2e eq %.2e du %.2e dp %.2e "
                        "active %d%s",
                        k,
                        fpr,
                        feas,
                        comp,
                        eq,
                        du,
                        dp,
                        active,
                        " (proposal rejected)" if rejected else _NOTES[proposal],
                    )
                    if self.stopping == "change":
                        done = du <= self.rtol and dp <= self.rtol
                    else:
                        done = max(fpr, feas, comp, eq) <= self.rtol
                    if done:
                        # the test's residuals come from identities that assume exact
                        # step-1 solves: confirm them independently before stopping
                        kkt = compute_kkt_residuals(problem, x, lam)
                        status = self._verdict(kkt, eq)
                        if status != "continue":
                            break
                        logger.info(
                            "ADMM %4d: the test was met, but the recomputed KKT residual "
                            "%.2e exceeds kkt_tol: going on",
                            k,
                            kkt.max(),
                        )
                        kkt = None
                    if callback is not None and self._ask_callback(callback, k, x, lam):
                        status = "callback"
                        break
                    if rejected:
                        z, proposal = accepted[0].copy(), _PLAIN  # the plain step instead
                        continue
                    accepted = (Tz, res)
                    proposal = _PLAIN
                    z = Tz
                    if mixer is not None:
                        candidate = mixer.update(np.concatenate([p_in, lam_in]), Tz)
                        if candidate is not None:
                            candidate[:m] = np.minimum(candidate[:m], g)
                            candidate[m:] = np.maximum(candidate[m:], 0.0)
                            z, proposal = candidate, _ANDERSON
                    if polisher is not None and polished_at is None:
                        budget = time.perf_counter() - t0 - polisher.time
                        exact = polisher.attempt(nu, r * p_in - lam_in, lam > 0.0, budget)
                        if exact is not None:
                            z, proposal = np.concatenate(exact), _POLISHED
                t_iter = time.perf_counter() - t0
            u.x.scatter_forward()

            t0 = time.perf_counter()
            if kkt is None:
                kkt = compute_kkt_residuals(problem, x, lam)
            t_kkt = time.perf_counter() - t0
        finally:
            for vec in (x_old, b0, b):
                vec.destroy()

        pressure = problem.pressure_function(lam)
        timings = {
            "assembly": problem.timings.get("assembly", 0.0),
            "penalty": (self.penalty_estimate.time if self.penalty_estimate else 0.0)
            + (self.surface_penalty.time if self.surface_penalty else 0.0)
            + self._time_schur,
            "operator": self.operator.timings["operator"]
            + (self.polisher.setup_time if self.polisher else 0.0),
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
        converged = status == "converged"
        result = ADMMResult(
            u=u,
            pressure=pressure,
            converged=converged,
            status=status,
            iterations=iterations,
            penalty=r,
            history=history,
            timings=timings,
            kkt=kkt,
            multiplier=lam,
            num_active=history["active"][-1],
            num_contact_nodes=c.num_global,
            settings=self.settings,
            extra={
                "max_pressure": problem.global_norm(lam, np.inf),
                "penalty_estimate": self.penalty_estimate.as_dict()
                if self.penalty_estimate
                else None,
                "surface_penalty": self.surface_penalty.as_dict() if self.surface_penalty else None,
                "projection": projection.statistics() if projection is not None else None,
                "polish": {
                    "polished_at": polished_at,
                    "attempts": polisher.attempts,
                    "rounds": polisher.rounds,
                    "skipped": polisher.skipped,
                    "time": polisher.time,
                }
                if polisher is not None
                else None,
            },
        )
        result.extra["warning"] = self._slow_convergence_warning(history, converged)
        if result.extra["warning"]:
            logger.warning("%s", result.extra["warning"])
        if status not in ("converged", "callback"):
            raise ADMMConvergenceError(self._failure_message(result), result)
        logger.info("%s", result.summary())
        return result

    # ------------------------------------------------------------------ verdicts
    def _verdict(self, kkt: KKTResiduals, loop_equilibrium: float) -> str:
        """What a met stopping test means, given the KKT residuals recomputed from (u, λ).

        Returns:
            ``"converged"``; ``"continue"`` (the loop's residuals and the recomputed
            ones differ by their definitions only: iterate on); ``"inexact_step1"``
            (the equilibrium identity of the loop is off: the step-1 solves are not
            exact); ``"inaccurate"`` (the change test stopped a stagnated iteration).
        """
        if kkt.max() <= self.kkt_tol:
            return "converged"
        if kkt.equilibrium > 10.0 * max(self.kkt_tol, loop_equilibrium):
            return "inexact_step1"
        return "inaccurate" if self.stopping == "change" else "continue"

    def _ask_callback(self, callback, k: int, x: PETSc.Vec, lam: np.ndarray) -> bool:
        """The user's callback on every rank; True if any rank asks to stop; collective."""
        answer = collective_call(self.problem.comm, lambda: callback(k, x, lam), "The callback")
        stop, unanimous = agree(self.problem.comm, bool(answer))
        if stop and not unanimous:
            logger.warning("ADMM: the callback asked to stop on some ranks only; stopping.")
        return stop

    def _failure_message(self, result: ADMMResult) -> str:
        """Why a solve did not converge, and what to do about it."""
        k, h, r = result.kkt, result.history, self.penalty
        residuals = (
            f"KKT residuals recomputed from (u, λ): penetration {k.primal_feasibility:.2e}, "
            f"complementarity {k.complementarity:.2e}, equilibrium {k.equilibrium:.2e}"
        )
        hand = self.penalty_estimate is None and self.surface_penalty is None
        if result.status == "inexact_step1":
            return (
                f"ADMM's stopping test was met after {result.iterations} iterations, but the "
                f"equilibrium residual recomputed from (u, λ) is {k.equilibrium:.2e} where "
                f"the iteration's identity gives {h['equilibrium'][-1]:.2e}: the step-1 "
                f"solves are not exact (petsc_options {self._petsc_options}). Use the "
                "default factorisation, or tighten the iterative solver (ksp_rtol ≤ 1e-10). "
                "The partial result is attached as `err.result`."
            )
        if result.status == "inaccurate":
            return (
                f"ADMM's relative-change test was met after {result.iterations} iterations "
                f"at r = {r:.6g}, but the iteration had stagnated, not converged: {residuals}, "
                f"above kkt_tol = {self.kkt_tol:g}. "
                + (
                    "r set by hand is far from the balanced penalty: use penalty='auto'. "
                    if hand
                    else "Use the 'kkt' stopping test (mode='accelerated'). "
                )
                + "The partial result is attached as `err.result`."
            )
        advice = (
            "use penalty='auto' (r set by hand is the usual cause of a slow ADMM), or "
            "increase max_iter"
            if hand
            else "increase max_iter"
        )
        return (
            f"ADMM did not converge in {self.max_iter} iterations at r = {r:.6g} "
            f"({self.stopping!r} test at rtol = {self.rtol:.1e}; last residuals: fpr "
            f"{h['fpr'][-1]:.2e}, equilibrium {h['equilibrium'][-1]:.2e}, du "
            f"{h['du'][-1]:.2e}, dp {h['dp'][-1]:.2e}; {residuals}): {advice}. The partial "
            "result is attached as `err.result`."
        )

    def _slow_convergence_warning(self, history: dict, converged: bool) -> str:
        """A loud note when the iteration was slow, with its observed contraction."""
        n = len(history["fpr"])
        if n < SLOW_ITERATIONS:
            return ""
        tail = np.asarray(history["fpr"][-20:], dtype=float)
        tail = tail[tail > 0]
        rate = float(np.exp(np.mean(np.diff(np.log(tail))))) if tail.size > 2 else float("nan")
        origin = "r*" if self.penalty_estimate else "given by hand"
        return (
            f"ADMM {'needed' if converged else 'ran'} {n} iterations (contraction of the "
            f"fixed-point residual ≈ {rate:.4f} per iteration) at r = {self.penalty:.6g} "
            f"({origin}). This is slow: "
            + (
                "use penalty='auto' (r*), which balances the extreme modes."
                if not self.penalty_estimate
                else "the contact zone may be badly resolved, or try anderson > 0."
            )
        )

    # ------------------------------------------------------------------ lifetime
    def destroy(self) -> None:
        """Free the KSP, the step-1 operator and the surface metric's objects; collective."""
        if getattr(self, "operator", None) is not None:
            self.operator.destroy()
        if getattr(self, "polisher", None) is not None:
            self.polisher.destroy()
        for name in ("_projection", "_metric"):
            obj = getattr(self, name, None)
            if obj is not None:
                obj.destroy()
                setattr(self, name, None)

    def __enter__(self) -> ADMMSolver:
        return self

    def __exit__(self, *exc) -> None:
        self.destroy()
