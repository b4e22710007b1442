"""What a solver does with its settings on a given problem, and why: the "auto" rules.

Every automatic choice of the package is made here, once, before the first solve, and
the plan says what it chose and why (``solver.plan.describe()``, printed by
``summary()``):

* step 1: a factorisation of A condensed onto Γ_C (2D or a 3D body held by the
  contact alone, one process, where the dense work is cheap:
  :func:`~admm_dolfinx.operators.condensed.condensed_factor_applies`), a
  factorisation of A + rK, or conjugate gradients with multigrid (an inexact ADMM).
  In 3D, with ``step1="auto"`` and no solver options: multigrid if the factorisation
  would need more than :data:`MEMORY_FRACTION` of the available memory or more than
  :data:`FACTOR_FLOPS_LIMIT` operations (where the multigrid path is faster:
  ``python benchmarks/step1_crossover.py`` measures both sides of it). What it would need is
  bracketed from the mesh (:mod:`~admm_dolfinx.linalg.factor_prediction`), and MUMPS's
  analysis (:func:`~admm_dolfinx.linalg.factor_estimate.mumps_estimate`) is run only
  where the bracket's two ends lead to different choices. With ``mode="paper"`` only memory counts:
  the paper's algorithm factorises step 1;
* r*: dense (from the condensed factorisation), local (no factorisation of the body)
  or factorised, unless the penalty is given, and its eigenvalue tolerance (looser in
  the surface metric, which uses λ_min and λ_max roughly);
* polishing: dense (the compliance of Γ_C, where S_C is at hand), inverse (the same
  compliance read off step 1's own factors by MUMPS's selected inverse entries: a 3D
  body that the contact alone holds, Γ_C past the condensed rule but
  within :data:`INVERSE_MAX_CONTACT_NODES` and :data:`INVERSE_MEMORY_FRACTION`),
  sparse (2D, factorisations of the body; or multigrid solves of the body, for one
  that the contact alone holds on the multigrid path, where the ADMM alone builds the
  contact zone a few nodes per iteration), or none;
* the penalty metric: the paper's r M, or the surface metric r(M + βL_Γ) (3D);
* an iterative step 1's inner tolerances (:mod:`admm_dolfinx.admm.inexact`): σ by
  whether the Dirichlet conditions hold the body (its outer iteration contracts fast)
  or the contact alone does.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from mpi4py import MPI

from admm_dolfinx.admm.inexact import SIGMA_FLOATING, SIGMA_HELD
from admm_dolfinx.admm.settings import ADMMSettings
from admm_dolfinx.linalg.factor_estimate import available_memory, mumps_estimate
from admm_dolfinx.linalg.factor_prediction import mesh_volume, predict_factorisation
from admm_dolfinx.linalg.mumps_schur import CENTRALISED_RHS
from admm_dolfinx.linalg.petsc import is_factorisation, iterative_options
from admm_dolfinx.operators.condensed import condensed_factor_applies
from admm_dolfinx.penalty.estimate import DEFAULT_PENALTY_TOL, automatic_method
from admm_dolfinx.penalty.surface import SURFACE_PENALTY_TOL
from admm_dolfinx.problem.contact_problem import ContactProblem

__all__ = [
    "FACTOR_FLOPS_LIMIT",
    "INVERSE_MAX_CONTACT_NODES",
    "INVERSE_MEMORY_FRACTION",
    "MEMORY_FRACTION",
    "SolverPlan",
    "make_plan",
]

#: In 3D, a factorisation estimated to need more than this fraction of the memory
#: available is not attempted: step 1 uses multigrid.
MEMORY_FRACTION = 0.5
#: In 3D, a factorisation that would cost more operations than this is
#: slower than the multigrid path on the whole solve (the crossover that
#: ``python benchmarks/step1_crossover.py`` measures on held bodies), for a floating
#: body too, which the multigrid path polishes (``python benchmarks/floating_3d.py``
#: compares it with the factorised path and its inverse entries).
FACTOR_FLOPS_LIMIT = 1e10
#: Polishing from step 1's factors (``polish="inverse"``) holds the c × c block of
#: (A + rK)⁻¹ (c ≤ 3m dofs of Γ_C) and its pattern, about 24 c² bytes: at most this
#: fraction of the memory available...
INVERSE_MEMORY_FRACTION = 0.25
#: ...and solves m × m dense systems per active-set round: at most this many contact
#: nodes.
INVERSE_MAX_CONTACT_NODES = 5000


@dataclass(frozen=True)
class SolverPlan:
    """The resolved choices of a solver.

    Attributes:
        step1: ``"condensed"``, ``"factorised"`` or ``"iterative"``.
        penalty: How r is found: ``"given"``, ``"dense"``, ``"local"``, ``"factorised"``.
        penalty_tol: The eigenvalue tolerance of the iterative r* methods (None with
            a given penalty).
        polish: ``"dense"`` (from S_C), ``"inverse"`` (from step 1's factors),
            ``"sparse"`` or ``"none"``.
        metric: ``"mass"`` or ``"surface"``.
        private_schur: A condensed factorisation is made for r* and polishing only
            (freed once S_C is read): step 1 factorises A + rK.
        step1_options: The options of the step-1 solver.
        ksp_rtol: The tolerance of an iterative step 1: ``"auto"`` (the inexact rule,
            tied to the outer residual), a number (``petsc_options["ksp_rtol"]``), or
            None (a direct solve).
        inner_sigma: σ of the inexact rule (with ``ksp_rtol`` ``"auto"``), else None.
        step1_basis: What chose between a factorisation and multigrid for step 1:
            ``"settings"`` (the user's settings or options, 2D, or an explicit
            condensed step), ``"mesh"`` (the mesh's bracket of the factorisation's
            cost, :mod:`~admm_dolfinx.linalg.factor_prediction`), ``"analysis"``
            (MUMPS's analysis) or ``"fallback"`` (a factorisation, the analysis having
            failed).
        reasons: Why, in words.
    """

    step1: str
    penalty: str
    penalty_tol: float | None
    polish: str
    metric: str
    private_schur: bool
    step1_options: dict
    ksp_rtol: str | float | None
    inner_sigma: float | None
    step1_basis: Literal["settings", "mesh", "analysis", "fallback"]
    reasons: tuple[str, ...]

    def describe(self) -> str:
        """One line: the choices and their reasons."""
        tol = "" if self.penalty_tol is None else f" (tol {self.penalty_tol:g})"
        return (
            f"step 1 {self.step1}, r* {self.penalty}{tol}, polish {self.polish}, "
            f"metric {self.metric} ({'; '.join(self.reasons)})"
        )


def make_plan(problem: ContactProblem, settings: ADMMSettings) -> SolverPlan:
    """Resolve the automatic choices of ``settings`` for ``problem``.

    Raises:
        ValueError: For a choice the problem cannot take (e.g. ``condensed=True`` under
            MPI, the surface metric in 2D), naming the fix.
    """
    options = dict(settings.petsc_options)
    auto = settings.penalty == "auto"
    serial = problem.comm.size == 1
    gdim = problem.gdim
    reasons = [f"{gdim}D", "one process" if serial else f"{problem.comm.size} processes"]
    iterative, basis, why = _iterative_step1(problem, settings, options)
    reasons.append(why)
    if iterative:
        options = iterative_options(options)
    factor = is_factorisation(options)
    explicit = settings.condensed is True or settings.polish is True
    schur_possible = condensed_factor_applies(problem, options, any_dimension=explicit)
    if settings.condensed is True and not (serial and schur_possible):
        raise ValueError(
            "expert condensed=True needs one process and a MUMPS factorisation (PETSc "
            "solves with a Schur complement serially only); drop it."
        )
    if settings.polish is True and not factor:
        raise ValueError(
            "polish=True needs the Schur complement of A onto the contact dofs, from a "
            "MUMPS factorisation (ksp_type preonly, pc_type cholesky or lu); got "
            f"petsc_options={options}. Pass polish=None."
        )
    condensed = settings.condensed
    if condensed is None:
        condensed = serial and schur_possible and (auto or settings.polish is True)
    step1 = "condensed" if condensed else ("factorised" if factor else "iterative")
    # dense polishing works in the paper's metric (its compliance is that of A + rNᵀMN):
    # with the surface metric asked for, the default (polish=None) does not polish
    may_polish = settings.polish is not False and settings.penalty_metric != "surface"
    schur = condensed or (schur_possible and may_polish and (auto or bool(settings.polish)))
    if schur and may_polish:
        polish = "dense"
        reasons.append("the dense Schur complement onto Γ_C is cheap here")
    elif (
        may_polish
        and (auto or settings.polish)
        and gdim == 3
        and _inverse_applies(problem, options, condensed)
    ):
        polish = "inverse"
        reasons.append(
            "a floating body, Γ_C too large for the condensed factorisation: T from the "
            "step-1 factors' inverse entries"
        )
    elif may_polish and (auto or settings.polish) and gdim == 2 and factor:
        polish = "sparse"
        reasons.append("Γ_C too large for dense polishing: sparse factorisations")
    elif may_polish and auto and step1 == "iterative" and problem.rigid_motions.floating:
        polish = "sparse"
        reasons.append(
            "a floating body on the multigrid path: the active-set walk solves by multigrid"
        )
    else:
        polish = "none"
    metric = "mass"
    if settings.penalty_metric == "surface":
        if gdim != 3:
            raise ValueError(
                "expert penalty_metric='surface' is for 3D bodies (a contact surface); "
                "this one is 2D: drop it (or pass expert={'penalty_metric': 'mass'})."
            )
        metric = "surface"
    elif (
        settings.penalty_metric == "auto"
        and gdim == 3
        and auto
        and settings.mode == "accelerated"
        and polish in ("none", "sparse")  # the sparse polish does not depend on r
    ):
        metric = "surface"
        reasons.append("3D: the surface metric keeps the iteration count flat")
    if metric == "surface":
        if settings.condensed is True:
            raise ValueError(
                "the surface metric penalises with Nᵀ(M + βL_Γ)N, which the condensed "
                "step 1 cannot: drop expert condensed=True (or pass "
                "expert={'penalty_metric': 'mass'})."
            )
        # a step 1 condensed onto the metric M cannot penalise with Nᵀ(M + βL_Γ)N, so
        # A + rK is factorised; nothing polishes, so no S_C is wanted either
        if condensed:
            condensed, step1 = False, "factorised"
        schur = False
    if not auto:
        penalty = "given"
    elif settings.penalty_method != "auto":
        penalty = settings.penalty_method
    else:
        # the surface metric's β and r were calibrated with the local estimate (its
        # λ_min a layer's lower bound), and without polishing S_C would serve r* alone
        penalty = automatic_method(problem, options, schur=schur) if metric == "mass" else "local"
    if (
        penalty == "dense"
        and not schur
        and not condensed_factor_applies(problem, options, any_dimension=True)
    ):
        raise ValueError(
            "expert penalty_method='dense' needs a MUMPS factorisation of the body "
            "condensed onto Γ_C; use penalty_method 'local' or 'factorised'."
        )
    ksp_rtol: str | float | None = None
    inner_sigma = None
    if step1 == "iterative":
        ksp_rtol = float(options["ksp_rtol"]) if "ksp_rtol" in options else "auto"
    if ksp_rtol == "auto":
        inner_sigma = settings.inner_sigma
        if inner_sigma is None:
            floating = problem.rigid_motions.floating
            inner_sigma = SIGMA_FLOATING if floating else SIGMA_HELD
            reasons.append(
                f"inner tolerance σ r with σ = {inner_sigma:g}: "
                + ("the contact alone holds the body" if floating else "a held body")
            )
    penalty_tol = settings.penalty_tol
    if penalty == "given":
        penalty_tol = None
    elif penalty_tol is None:
        penalty_tol = SURFACE_PENALTY_TOL if metric == "surface" else DEFAULT_PENALTY_TOL
    return SolverPlan(
        step1=step1,
        penalty=penalty,
        penalty_tol=penalty_tol,
        polish=polish,
        metric=metric,
        private_schur=bool(schur and not condensed),
        # reading inverse entries under MPI needs a centralised right-hand side
        step1_options=(
            {**options, **CENTRALISED_RHS} if polish == "inverse" and not serial else options
        ),
        ksp_rtol=ksp_rtol,
        inner_sigma=inner_sigma,
        step1_basis=basis,
        reasons=tuple(reasons),
    )


def _inverse_applies(problem: ContactProblem, options: dict, condensed: bool):
    """Whether T can be read off a factorised step 1 (see ``INVERSE_*``); collective."""
    if not (is_factorisation(options) and not condensed):
        return False
    if not problem.rigid_motions.floating:
        return False
    m = problem.contact.num_global
    if m > INVERSE_MAX_CONTACT_NODES:
        return False
    c = problem.comm.allreduce(int(np.count_nonzero(problem.contact.free_normals)))
    return 24.0 * float(c) ** 2 <= INVERSE_MEMORY_FRACTION * _smallest_memory(problem)


def _smallest_memory(problem: ContactProblem) -> float:
    """Bytes available, the smallest figure over the ranks (the same on all); collective.

    On one machine every rank sees the same total; the minimum keeps every rank's
    choice the same where machines differ.
    """
    return problem.comm.allreduce(available_memory() or float("inf"), op=MPI.MIN)


def _iterative_step1(problem: ContactProblem, settings: ADMMSettings, options: dict):
    """(whether step 1 is iterative, what decided it, why in words); collective."""
    if settings.step1 == "iterative":
        return True, "settings", "step1='iterative': CG + multigrid"
    if options.get("ksp_type", "preonly") != "preonly":
        return True, "settings", f"an iterative step 1 from petsc_options {options}"
    if settings.step1 == "factorised" or options:
        return False, "settings", "MUMPS factorisation"
    if problem.gdim != 3 or settings.condensed is True or settings.polish is True:
        return False, "settings", "MUMPS factorisation"
    rule = _StepOneRule(memory=_smallest_memory(problem), paper=settings.mode == "paper")
    # the mesh's bracket first: where both its ends lead to the same choice, MUMPS's
    # analysis, whose figures lie inside it, would lead there too (the rule is monotone)
    bracket = predict_factorisation(
        problem.bounds[1] - problem.bounds[0],
        mesh_volume(problem.mesh),
        problem.A.getSize()[0],
        processes=problem.comm.size,
    )
    if bracket is not None:
        cheap, why_cheap = rule.iterative_at(bracket.flops[0], bracket.memory[0])
        dear, why_dear = rule.iterative_at(bracket.flops[1], bracket.memory[1])
        if cheap == dear:
            # the binding rule: the cheapest cost already iterative, the dearest factorised
            return (
                cheap,
                "mesh",
                f"{'CG + multigrid' if cheap else 'MUMPS factorisation'}: the mesh bounds a "
                f"factorisation at {bracket.flops[0]:.1e} to {bracket.flops[1]:.1e} flops and "
                f"{bracket.memory[0] / 1e9:.2g} to {bracket.memory[1] / 1e9:.2g} GB, "
                f"{why_cheap if cheap else why_dear} (MUMPS's analysis not needed)",
            )
    estimate = mumps_estimate(problem.A, prefix=settings.prefixes["estimate"])
    if estimate is None:
        return False, "fallback", "MUMPS factorisation (no analysis available to compare)"
    iterative, why = rule.iterative_at(estimate.flops, estimate.memory)
    need = f"{estimate.memory / 1e9:.3g} GB and {estimate.flops:.3g} flops"
    return (
        iterative,
        "analysis",
        f"{'CG + multigrid' if iterative else 'MUMPS factorisation'}: MUMPS's analysis "
        f"says a factorisation would need {need} ({why})",
    )


@dataclass(frozen=True)
class _StepOneRule:
    """Multigrid or a factorisation, by what the factorisation would cost.

    Attributes:
        memory: The bytes available (the smallest figure over the ranks).
        paper: The paper's mode: a factorisation wherever it fits.
    """

    memory: float
    paper: bool

    def iterative_at(self, flops: float, need: float) -> tuple[bool, str]:
        """(whether step 1 is iterative, the rule that says so) at this cost.

        Monotone: a factorisation chosen at some (flops, need) is chosen at any
        smaller one, and multigrid at any larger one.
        """
        if need > MEMORY_FRACTION * self.memory:
            return True, (
                f"more than {MEMORY_FRACTION:g} of the {self.memory / 1e9:.3g} GB available"
            )
        if self.paper:
            # the paper's Algorithm 2 factorises step 1 once: kept wherever it fits
            return False, "it fits: factorised as the paper's algorithm"
        if flops > FACTOR_FLOPS_LIMIT:
            return True, f"> {FACTOR_FLOPS_LIMIT:.0e} flops, where multigrid is faster"
        return False, f"≤ {FACTOR_FLOPS_LIMIT:.0e} flops and it fits"
