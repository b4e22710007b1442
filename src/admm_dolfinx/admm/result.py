"""The outcome of a solve: typed, with its status, timings and what the solver did."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt
from dolfinx import fem, mesh

from admm_dolfinx.admm.settings import ADMMSettings
from admm_dolfinx.penalty.estimate import PenaltyEstimate
from admm_dolfinx.penalty.surface import SurfacePenalty
from admm_dolfinx.problem.contact_set import Marker
from admm_dolfinx.problem.kkt import KKTResiduals
from admm_dolfinx.problem.penetration import ObstaclePenetration
from admm_dolfinx.problem.resolution import ContactResolution

if TYPE_CHECKING:
    from admm_dolfinx.problem.contact_problem import ContactProblem

__all__ = [
    "STATUSES",
    "ADMMConvergenceError",
    "ADMMResult",
    "PolishInfo",
    "Step1Info",
    "Timings",
    "WarmStart",
]

#: ``ADMMResult.status`` values and what they mean.
STATUSES = {
    "converged": "converged",
    "callback": "stopped by the callback (not converged)",
    "max_iter": "NOT CONVERGED (iteration limit)",
    "inaccurate": "NOT CONVERGED (stagnated: KKT residuals above tolerance)",
    "inexact_step1": "NOT CONVERGED (inexact step-1 solves)",
}


@dataclass(frozen=True)
class Timings:
    """Wall-clock seconds of a solve, phase by phase (one home: ``dolfinx.common.Timer``).

    Attributes:
        assembly: Building the problem's operators (once per problem).
        penalty: r* (and the surface metric's β and μ_max; a private condensed
            factorisation for it included).
        operator: Forming A + rK (and the dense compliance when polishing densely).
        factorization: Factorising step 1's operator (an iterative one: setting its
            preconditioner up, the multigrid hierarchy included).
        iterations: The ADMM loop (polishing included).
        kkt: The final KKT check.
        total: All of the above.
    """

    assembly: float = 0.0
    penalty: float = 0.0
    operator: float = 0.0
    factorization: float = 0.0
    iterations: float = 0.0
    kkt: float = 0.0
    total: float = 0.0

    def __getitem__(self, name: str) -> float:
        """``timings["iterations"]``: the same as ``timings.iterations``."""
        if name not in self.names():
            raise KeyError(name)
        return float(getattr(self, name))

    @classmethod
    def names(cls) -> tuple[str, ...]:
        """The phases."""
        return tuple(f.name for f in fields(cls))

    def items(self):
        """(phase, seconds) pairs."""
        return asdict(self).items()

    def as_dict(self) -> dict[str, float]:
        """Plain numbers for reports and JSON."""
        return asdict(self)


@dataclass(frozen=True)
class Step1Info:
    """What an iterative step 1 did in one solve (the inexact ADMM).

    Attributes:
        krylov_iterations: Krylov (CG) iterations over every step-1 solve.
        solves: Step-1 solves.
        unconverged: Solves that stopped at their iteration limit.
        last_rtol: The relative tolerance of the last solve.
        tightened: How often the KKT check made the tolerances tighter.
        time: Seconds in the step-1 solves (part of ``timings.iterations``).
    """

    krylov_iterations: int
    solves: int
    unconverged: int
    last_rtol: float
    tightened: int
    time: float = 0.0


@dataclass(frozen=True)
class PolishInfo:
    """What active-set polishing did in a solve.

    Attributes:
        kind: ``"dense"`` (the compliance of Γ_C), ``"inverse"`` (the same, read off
            step 1's factors) or ``"sparse"`` (solves with the body: factorisations, or
            multigrid on the multigrid path).
        polished_at: The iteration that evaluated the polished state, or None.
        attempts: Guesses tried.
        rounds: Active-set rounds (dense solves, or solves with the body).
        skipped: Attempts skipped because polishing had taken longer than the rest of
            the iterations.
        time: Seconds within the iterations.
        krylov_iterations: Krylov iterations of the rounds' solves (0 where they are
            direct).
    """

    kind: str
    polished_at: int | None
    attempts: int
    rounds: int
    skipped: int
    time: float
    krylov_iterations: int = 0

    def __getitem__(self, name: str) -> Any:
        """Dictionary-style access to the fields."""
        return getattr(self, name)

    def as_dict(self) -> dict[str, Any]:
        """Plain values."""
        return asdict(self)


@dataclass(repr=False)
class ADMMResult:
    """Outcome of :meth:`ADMMSolver.solve`.

    Attributes:
        u: Displacement, a Function on the problem's space.
        pressure: Contact pressure λ ≥ 0 as a P1 scalar Function, zero off Γ_C.
        converged: Whether the solve converged: the stopping test was met *and* the
            relative KKT residuals recomputed from (u, λ) after the loop (:attr:`kkt`)
            are at most ``settings.kkt_tol``. True for every returned result except a
            callback stop.
        status: A key of :data:`STATUSES`: ``"converged"``; ``"callback"`` (returned
            with ``converged=False``); on the result attached to an
            :class:`ADMMConvergenceError`: ``"max_iter"``, ``"inaccurate"`` (the test
            was met but the recomputed KKT residuals exceed ``kkt_tol``: the iteration
            stagnated) or ``"inexact_step1"`` (the step-1 solves are not exact enough
            for the loop's residual identity).
        iterations: Number of ADMM iterations (= step-1 solves, rejected Anderson
            steps included).
        penalty: The penalty parameter r that was used.
        history: Per-iteration lists: ``du``, ``dp`` (relative changes of u and p),
            ``fpr`` (scaled fixed-point residual), ``feasibility``, ``complementarity``,
            ``equilibrium`` (relative KKT residuals), ``active`` (global number of
            nodes with λ > 0) and ``accelerated`` (what the evaluated state was: 0 a
            plain step, 1 an accepted Anderson extrapolation, 2 an accepted polished
            state, −1 a rejected proposal).
        timings: Seconds per phase.
        kkt: Relative KKT residuals of (u, λ), computed independently.
        multiplier: λ at the owned contact nodes (local array).
        num_active: Global number of contact nodes with λ > 0.
        num_contact_nodes: Global number m of contact nodes.
        settings: The solver's settings.
        plan: What the solver chose and why (:class:`~admm_dolfinx.admm.plan.SolverPlan`).
        max_pressure: max λ over Γ_C.
        contact_force: The total force of the obstacle on the body, a gdim vector
            (:func:`admm_dolfinx.problem.forces.contact_force`). With the support
            reactions and the applied loads it balances to ``kkt.force_balance`` ×
            max(‖F_c‖, ‖F_ext‖), at most ``kkt_tol`` of it in a converged result.
        applied_load: The resultant F_ext of the applied loads (of ``L``).
        contact_area: The measure of the contact zone, Σ M_jj over the active nodes
            (a length in 2D; :func:`admm_dolfinx.problem.contact_zone.contact_area`).
        mean_pressure: The mean pressure over the contact zone.
        problem: The problem that was solved (for the collective outputs below).
        penalty_estimate: The r* estimate, if the penalty was automatic.
        surface_penalty: β and r of the surface metric, if it was used.
        polish: What polishing did (None when off).
        projection: The surface metric's QP statistics (active-set ``rounds``,
            ``factorisations``), if it was used.
        step1: An iterative step 1's work in this solve (None for a direct one).
        obstacle_penetration: How deep the deformed contact nodes enter the obstacle
            itself, not its linearisation (None in the paper's model):
            :mod:`admm_dolfinx.problem.penetration`.
        resolution: Whether the mesh resolves the contact zone around the pressure
            peak, with an estimate of the peak pressure's error
            (:mod:`admm_dolfinx.problem.resolution`).
        warning: Non-empty when the solve was slow (with the observed contraction rate
            and the likely cause), when the deformed body enters the obstacle beyond
            the tolerance (where, and why), or when the contact zone is under-resolved
            (the estimated error of the peak pressure, and the fix).
    """

    u: fem.Function
    pressure: fem.Function
    converged: bool
    status: str
    iterations: int
    penalty: float
    history: dict[str, list[float]]
    timings: Timings
    kkt: KKTResiduals
    multiplier: npt.NDArray[np.float64]
    num_active: int
    num_contact_nodes: int
    settings: ADMMSettings
    plan: Any = None
    max_pressure: float = 0.0
    contact_force: npt.NDArray[np.float64] | None = None
    applied_load: npt.NDArray[np.float64] | None = None
    contact_area: float = 0.0
    mean_pressure: float = 0.0
    problem: ContactProblem | None = field(default=None, repr=False, compare=False)
    penalty_estimate: PenaltyEstimate | None = None
    surface_penalty: SurfacePenalty | None = None
    polish: PolishInfo | None = None
    projection: dict[str, int] | None = None
    step1: Step1Info | None = None
    obstacle_penetration: ObstaclePenetration | None = None
    resolution: ContactResolution | None = None
    warning: str = ""

    def _solved_problem(self) -> ContactProblem:
        if self.problem is None:
            raise RuntimeError("This result does not know its problem (it was built by hand).")
        return self.problem

    def reaction_force(self, marker: Marker) -> npt.NDArray[np.float64]:
        """The force of the supports on the facets tagged ``marker`` (tag or tuple); collective.

        See :func:`admm_dolfinx.problem.forces.reaction_force`.
        """
        from admm_dolfinx.problem.forces import reaction_force

        return reaction_force(self._solved_problem(), self.u, marker, self.multiplier)

    def gap(self) -> fem.Function:
        """The remaining gap g − N u as a Function, zero off Γ_C; collective."""
        from admm_dolfinx.problem.contact_zone import gap_function

        return gap_function(self._solved_problem(), self.u)

    def active_marker(self) -> fem.Function:
        """The active set as a Function: 1 at contact nodes with λ > 0, else 0; collective."""
        from admm_dolfinx.problem.contact_zone import active_marker

        return active_marker(self._solved_problem(), self.multiplier)

    def active_facets(self, value: int = 1) -> mesh.MeshTags:
        """The facets of Γ_C in contact (all vertices active) as MeshTags; collective."""
        from admm_dolfinx.problem.contact_zone import active_facets

        return active_facets(self._solved_problem(), self.multiplier, value)

    @property
    def polished(self) -> bool:
        """Whether the solve ended from a polished (exact active-set) state."""
        return self.polish is not None and self.polish.polished_at is not None

    @property
    def _gdim(self) -> int:
        return 0 if self.contact_force is None else int(np.size(self.contact_force))

    @staticmethod
    def _vector_text(vector: npt.NDArray[np.float64] | None) -> str:
        if vector is None:
            return "–"
        return "(" + ", ".join(f"{value:.6g}" for value in vector) + ")"

    def _resolution_text(self) -> str:
        """The contact zone's resolution, in a few words."""
        r = self.resolution
        if r is None or r.where is None:
            return ""
        verdict = "resolved" if r.resolved else "UNDER-RESOLVED"
        if r.peak_error is None:
            return f"; contact zone {verdict}"
        return f"; contact zone {verdict} (peak pressure within about {abs(r.peak_error):.0%})"

    def _forces_text(self) -> str:
        """The forces on the body and how well they balance."""
        text = f"  contact force = {self._vector_text(self.contact_force)}"
        if self.contact_force is None or self.applied_load is None:
            return text
        supports = -(self.contact_force + self.applied_load)
        return (
            f"{text}, applied loads = {self._vector_text(self.applied_load)}, supports = "
            f"{self._vector_text(supports)} (the three balance to "
            f"{self.kkt.force_balance:.1e} × max(|contact|, |loads|))"
        )

    def __repr__(self) -> str:
        """One line: the verdict and the numbers (``summary()`` has the rest)."""
        return (
            f"ADMMResult(status={self.status!r}, converged={self.converged}, "
            f"iterations={self.iterations}, penalty={self.penalty:.6g}, "
            f"kkt_max={self.kkt.max():.2e}, num_active={self.num_active})"
        )

    def summary(self) -> str:
        """A short human-readable report (what the demos print)."""
        k, s, t = self.kkt, self.settings, self.timings
        est, surface = self.penalty_estimate, self.surface_penalty
        how = ""
        if est is not None:
            solves = f", {est.solves} solves" if est.details.get("method") != "dense" else ""
            how = (
                f" (r* by the {est.details.get('method')} method: λ_min {est.lambda_min:.4g}, "
                f"λ_max {est.lambda_max:.4g}{solves})"
            )
        if surface is not None:
            how = (
                f" in the surface metric r(M + βL_Γ), β = {surface.beta:.4g} "
                f"(from r* {surface.estimate.r:.6g}: λ_min {surface.estimate.lambda_min:.4g}, "
                f"λ_max {surface.estimate.lambda_max:.4g}; μ_max {surface.mu_max:.4g})"
            )
        lines = [
            f"ADMM {STATUSES.get(self.status, self.status)} in {self.iterations} iterations, "
            f"r = {self.penalty:.6g}{how}",
            f"  {s.mode} mode: alpha {s.alpha}, Anderson memory {s.anderson}, stopping "
            f"'{s.stopping}' at rtol {s.rtol:g} (KKT checked at {s.kkt_tol:g})",
        ]
        if self.plan is not None:
            lines.append(f"  plan: {self.plan.describe()}")
        lines += [
            f"  contact nodes m = {self.num_contact_nodes}, active (λ > 0) = {self.num_active}"
            + self._resolution_text(),
            f"  max pressure = {self.max_pressure:.6g}, mean pressure = "
            f"{self.mean_pressure:.6g}, contact {'length' if self._gdim == 2 else 'area'} = "
            f"{self.contact_area:.6g}",
            self._forces_text(),
            "  KKT residuals (relative): "
            f"feasibility {k.primal_feasibility:.2e}, complementarity "
            f"{k.complementarity:.2e}, equilibrium {k.equilibrium:.2e}, force balance "
            f"{k.force_balance:.2e}",
            "  time [s]: " + ", ".join(f"{name} {value:.3f}" for name, value in t.items()),
        ]
        if self.step1 is not None:
            i = self.step1
            lines.append(
                f"  step 1 (iterative): {i.krylov_iterations} Krylov iterations in "
                f"{i.solves} solves ({i.time:.3f} s), {i.unconverged} at their iteration "
                f"limit, last tolerance {i.last_rtol:.1e}"
                + (f" ({i.tightened} tightenings after the KKT check)" if i.tightened else "")
            )
        if self.polish is not None:
            p = self.polish
            at = p.polished_at
            lines.append(
                f"  polish ({p.kind}): "
                f"{'exact state from iteration ' + str(at) if at else 'not used'}"
                f" ({p.attempts} attempts, {p.rounds} active-set rounds"
                + (f", {p.krylov_iterations} Krylov iterations" if p.krylov_iterations else "")
                + f", {p.time:.3f} s)"
            )
        if self.warning:
            lines.append(f"  WARNING: {self.warning}")
        return "\n".join(lines)


@dataclass(frozen=True)
class WarmStart:
    """A start for :meth:`~admm_dolfinx.ADMMSolver.solve` other than an earlier result.

    Attributes:
        u: A displacement on the problem's space (e.g. a coarser mesh's, interpolated).
        multiplier: λ at the problem's owned contact nodes.
    """

    u: fem.Function
    multiplier: npt.NDArray[np.float64]


class ADMMConvergenceError(RuntimeError):
    """Raised when a solve does not converge (its ``result.status`` says why).

    Attributes:
        result: The (unconverged) result at the last iterate, ``converged=False``.
    """

    def __init__(self, message: str, result: ADMMResult):
        super().__init__(message)
        self.result = result
