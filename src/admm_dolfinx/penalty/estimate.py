"""The automatic penalty r* = 1/sqrt(λ_min λ_max) (Koko 2019, §4–5 and Algorithm 5).

ADMM contracts mode i of the dual error by abs(1 − rλ_i) / (1 + rλ_i), where λ_i are the
non-zero eigenvalues of A⁻¹NᵀMN, i.e. of the m × m pencil on the contact dofs

    M w = λ S w,     S = Schur complement of A onto the contact normal dofs,

so the best fixed r balances the two extremes: r* = 1/sqrt(λ_min λ_max). This module
is the one entry point; the method is an explicit choice (``method``):

* ``"dense"`` (the default in 2D, and for a 3D body that the contact alone holds,
  where the condensed factorisation is cheap): one
  factorisation of A condensed onto the contact dofs
  (:class:`~admm_dolfinx.operators.condensed.CondensedOperator`) gives the dense Schur
  complement S_C, from which the whole pencil follows
  (:func:`~admm_dolfinx.penalty.dense.extremes_from_schur`). Exact; the same on any
  number of processes to round-off; the ADMM then solves with the same factorisation.
* ``"local"`` (the default elsewhere): no factorisation of the whole body. λ_min on
  layers of cells along Γ_C (:mod:`admm_dolfinx.penalty.lambda_min`), grown until
  they agree to ``lambda_min_tol``; λ_max by multigrid LOBPCG on the full-space pencil
  (:mod:`admm_dolfinx.penalty.lambda_max`), to the eigenvalue tolerance ``tol``, and,
  through the multigrid's aggregates, dependent on the partition at that level.
  r* = 1/sqrt(λ_min λ_max) moves by half of λ_min's relative error, so r* to ``tol``
  needs λ_min to 2 ``tol`` only (the default of ``lambda_min_tol``); a caller that
  needs λ_min for less asks for less, or for one layer of ``lambda_min_rings`` rings
  with no growth (the surface metric's β, calibrated with it).
* ``"factorised"``: both ends by Krylov–Schur on operators applied with factorisations
  of the body (Â for the exact Schur complement, A + r_a NᵀMN for λ_max), in the
  solver's own operator so that the symbolic analysis is shared with step 1; exact
  to ``tol`` and the same on any partition to round-off. A floating body's λ_max is
  computed this way, except on the multigrid path: there LOBPCG deflates its free
  rigid motions and preconditions with step 1's multigrid of A + r_a K (A alone is
  singular), and Krylov–Schur with step 1's Krylov solves is the fallback.

:attr:`PenaltyEstimate.solves` counts operator applications: substitutions with a
factorisation, or AMG V-cycles. ``python benchmarks/penalty_accuracy.py`` measures
the methods against the dense pencil, ``python benchmarks/penalty_cost.py`` their cost.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from dolfinx.common import Timer
from petsc4py import PETSc

from admm_dolfinx._logging import get_logger, speaking_for
from admm_dolfinx._mpi import check_same_on_every_rank, raise_collectively
from admm_dolfinx.linalg.contact_space import ContactSpace
from admm_dolfinx.operators.condensed import CondensedOperator, condensed_factor_applies
from admm_dolfinx.operators.penalised import IterativeOperator, PenalisedOperator
from admm_dolfinx.penalty.dense import dense_extremes
from admm_dolfinx.penalty.lambda_max import (
    NeedsFactorisation,
    lambda_max_factorised,
    lambda_max_multigrid,
)
from admm_dolfinx.penalty.lambda_min import lambda_min_exact, lambda_min_from_layers
from admm_dolfinx.problem.contact_problem import ContactProblem

__all__ = [
    "DEFAULT_PENALTY_TOL",
    "PENALTY_METHODS",
    "PenaltyEstimate",
    "automatic_method",
    "estimate_penalty",
]

logger = get_logger(__name__)

#: Default relative tolerance of the eigenvalue solves. r* needs a few digits only;
#: see the README for how little it moves r*.
DEFAULT_PENALTY_TOL = 1e-2

#: ``method`` values of :func:`estimate_penalty`.
PENALTY_METHODS = ("auto", "dense", "local", "factorised")


@dataclass
class PenaltyEstimate:
    """Result of :func:`estimate_penalty`.

    Attributes:
        r: The penalty r* = 1/sqrt(λ_min λ_max).
        lambda_min: Smallest non-zero eigenvalue of A⁻¹NᵀMN.
        lambda_max: Largest finite eigenvalue of A⁻¹NᵀMN.
        solves: Linear solves (operator applications) used by both eigenvalue solves
            (0 for the dense method, which needs none beyond its factorisation).
        time: Wall-clock seconds, factorisations included (none when the caller's
            condensed factorisation was used).
        details: ``method`` (``"dense"`` or ``"iterative"``), ``rigid_modes``; dense:
            ``c`` (the number of contact dofs), ``time_factorization`` (0 if shared),
            ``time_dense``;
            iterative: solves and seconds per extreme (``solves_min``, ``time_min``,
            ``solves_max``, ``time_max``; ``time_multigrid_setup`` when λ_max came
            from multigrid, 0 with ``multigrid_shared``: step 1's hierarchy, set up
            by step 1; a floating body's is step 1's, set up here at r_a and counted),
            the auxiliary r_a.
        condition_number: κ = λ_max / λ_min; the ADMM rate at r* is (√κ − 1)/(√κ + 1).
    """

    r: float
    lambda_min: float
    lambda_max: float
    solves: int
    time: float
    details: dict[str, Any] = field(default_factory=dict)
    condition_number: float = field(init=False)

    def as_dict(self) -> dict[str, Any]:
        """Plain numbers for reports and JSON."""
        return {
            "r": self.r,
            "lambda_min": self.lambda_min,
            "lambda_max": self.lambda_max,
            "solves": self.solves,
            "time": self.time,
            "rigid_modes": self.details.get("rigid_modes", 0),
        }

    def __post_init__(self) -> None:
        #: κ = λ_max / λ_min; the ADMM rate at r* is (√κ − 1)/(√κ + 1).
        self.condition_number = self.lambda_max / self.lambda_min


def estimate_penalty(
    problem: ContactProblem,
    *,
    tol: float = DEFAULT_PENALTY_TOL,
    max_it: int = 500,
    method: str = "auto",
    operator: PenalisedOperator | CondensedOperator | None = None,
    petsc_options: dict | None = None,
    petsc_options_prefix: str | None = None,
    multigrid: PETSc.PC | None = None,
    lambda_min_tol: float | None = None,
    lambda_min_rings: int | None = None,
) -> PenaltyEstimate:
    """Compute r* = 1/sqrt(λ_min λ_max) with SLEPc on the contact dofs; collective.

    Args:
        problem: The contact problem.
        tol: Relative tolerance of both eigenvalue solves (SLEPc ``eps_tol``) of the
            ``"local"`` and ``"factorised"`` methods; the dense one is exact.
        max_it: Maximum Krylov–Schur restarts.
        method: ``"dense"``, ``"local"``, ``"factorised"`` (see the module docstring)
            or ``"auto"``: dense where the condensed factorisation is cheap
            (:func:`~admm_dolfinx.operators.condensed.condensed_factor_applies`), local
            otherwise.
        operator: The ADMM's operator, to share factorisations: a
            :class:`CondensedOperator` (dense method; nothing is factorised here), or
            a :class:`PenalisedOperator` (left factorised at r_a, its symbolic
            factorisation reused by the ADMM). A private one otherwise.
        petsc_options: Options of the factorisations (MUMPS Cholesky by default).
        petsc_options_prefix: Prefix (default ``"penalty_"``); sub-objects get
            ``schur_``, ``dense_``, ``layer_``, ``lmin_``, ``lmax_``, ``lmax_amg_``.
        multigrid: A multigrid preconditioner of A set up already (the iterative
            step 1's, :meth:`~admm_dolfinx.operators.penalised.IterativeOperator.set_up_hierarchy`)
            for the local method's λ_max, borrowed; it builds its own otherwise.
        lambda_min_tol: The local method's tolerance on λ_min's layer truncation (two
            successive layers agree to it), in (0, 1); default ``min(2 tol, 0.5)``,
            which keeps r* within ``tol``.
        lambda_min_rings: Instead of growing layers to ``lambda_min_tol``, the local
            method's λ_min on the layer of this many rings alone (0: the contact nodes
            alone, the rest held fixed): a lower bound of λ_min with no check of its
            truncation error, for a caller that uses λ_min roughly (the surface
            metric's β); r* is then not held to ``tol``.

    Returns:
        The estimate.

    Raises:
        ValueError: For a tolerance outside (0, 1), ``max_it`` < 1, an unknown method,
            or both ``lambda_min_tol`` and ``lambda_min_rings``.
        RuntimeError: If an eigenvalue solve does not converge.
    """
    arguments = {
        "tol": tol,
        "max_it": max_it,
        "method": method,
        "petsc_options": petsc_options,
        "petsc_options_prefix": petsc_options_prefix,
        "lambda_min_tol": lambda_min_tol,
        "lambda_min_rings": lambda_min_rings,
    }
    error = None
    try:  # an argument out of range on one rank raises on every rank
        _check_arguments(**arguments)
    except (TypeError, ValueError) as exc:
        error = exc
    raise_collectively(problem.comm, error, "estimate_penalty")
    check_same_on_every_rank(problem.comm, arguments, "estimate_penalty's arguments")
    if lambda_min_rings is None and lambda_min_tol is None:
        lambda_min_tol = min(2.0 * tol, 0.5)
    with speaking_for(problem.comm):
        return _estimate(
            problem,
            tol,
            max_it,
            method,
            operator,
            petsc_options,
            petsc_options_prefix or "penalty_",
            multigrid,
            lambda_min_tol,
            lambda_min_rings,
        )


def automatic_method(problem: ContactProblem, petsc_options: dict | None, *, schur: bool) -> str:
    """The r* method that ``method="auto"`` means: the one home of that rule; collective.

    ``"dense"`` (exact) where S_C is at hand (``schur``: a condensed factorisation the
    solver makes anyway) or cheap to make
    (:func:`~admm_dolfinx.operators.condensed.condensed_factor_applies`), ``"local"``
    otherwise.
    """
    return "dense" if schur or condensed_factor_applies(problem, petsc_options) else "local"


def _check_arguments(
    tol, max_it, method, petsc_options, petsc_options_prefix, lambda_min_tol, lambda_min_rings
) -> None:
    """Raise for an argument of :func:`estimate_penalty` out of its range."""
    if not (0.0 < tol < 1.0):
        raise ValueError(f"tol must lie in (0, 1), got {tol}.")
    if lambda_min_rings is not None:
        if lambda_min_tol is not None:
            raise ValueError(
                "lambda_min_tol grows λ_min's layers to a tolerance, lambda_min_rings fixes "
                "their number: give one of them."
            )
        if (
            isinstance(lambda_min_rings, bool)
            or not isinstance(lambda_min_rings, int | np.integer)
            or lambda_min_rings < 0
        ):
            raise ValueError(f"lambda_min_rings must be an integer ≥ 0, got {lambda_min_rings!r}.")
    elif lambda_min_tol is not None and not (0.0 < lambda_min_tol < 1.0):
        raise ValueError(f"lambda_min_tol must lie in (0, 1), got {lambda_min_tol}.")
    if isinstance(max_it, bool) or not isinstance(max_it, int | np.integer) or max_it < 1:
        raise ValueError(f"max_it must be an integer ≥ 1, got {max_it!r}.")
    if method not in PENALTY_METHODS:
        raise ValueError(f"method must be one of {PENALTY_METHODS}, got {method!r}.")


def _estimate(
    problem: ContactProblem,
    tol: float,
    max_it: int,
    method: str,
    operator: PenalisedOperator | CondensedOperator | None,
    petsc_options: dict | None,
    prefix: str,
    multigrid: PETSc.PC | None,
    lambda_min_tol: float | None,
    lambda_min_rings: int | None,
) -> PenaltyEstimate:
    """:func:`estimate_penalty` on checked arguments; collective."""
    t_start = time.perf_counter()
    shared_condensed = isinstance(operator, CondensedOperator)
    if method == "auto":
        method = automatic_method(problem, petsc_options, schur=shared_condensed)
    if method == "dense":
        condensed = operator if shared_condensed else None
        lambda_min, lambda_max, details = dense_extremes(problem, condensed, prefix, petsc_options)
        details["tol"] = 0.0
        return _finish(lambda_min, lambda_max, details, t_start)
    # a shared condensed operator: the iterative methods factorise other matrices, in a
    # private one
    if isinstance(operator, CondensedOperator):
        operator = None
    lambda_min, lambda_max, details = _iterative_extremes(
        problem,
        method,
        tol,
        max_it,
        operator,
        prefix,
        petsc_options,
        multigrid,
        lambda_min_tol,
        lambda_min_rings,
    )
    return _finish(lambda_min, lambda_max, details, t_start)


def _iterative_extremes(
    problem: ContactProblem,
    method: str,
    tol: float,
    max_it: int,
    operator: PenalisedOperator | None,
    prefix: str,
    petsc_options: dict | None,
    multigrid: PETSc.PC | None,
    lambda_min_tol: float | None,
    lambda_min_rings: int | None,
) -> tuple[float, float, dict[str, Any]]:
    """λ_min, λ_max and details by the ``"local"`` or ``"factorised"`` method; collective.

    The operator (shared with the ADMM, or a private one made here when a method
    needs a factorisation of the whole body) is only touched by the factorised parts.
    """
    space = ContactSpace(problem)
    own_operator = operator is None
    details: dict[str, Any] = {"method": method, "tol": tol, "m": space.m}
    if method == "local":
        details["lambda_min_tol"] = lambda_min_tol
        details["lambda_min_rings"] = lambda_min_rings
    start = space.start_vector()

    def shared_operator() -> PenalisedOperator:
        nonlocal operator
        if operator is None:
            operator = PenalisedOperator(problem, prefix, petsc_options)
        return operator

    try:
        with Timer("admm_dolfinx: r* lambda_min"):
            t0 = time.perf_counter()
            if method == "local":
                lambda_min, info = lambda_min_from_layers(
                    space,
                    tol,
                    max_it,
                    prefix,
                    petsc_options,
                    start,
                    lambda_min_tol,
                    rings=None if lambda_min_rings is None else int(lambda_min_rings),
                )
            else:
                lambda_min, info = lambda_min_exact(
                    space, shared_operator(), tol, max_it, prefix, start
                )
            details.update(info, time_min=time.perf_counter() - t0)
        with Timer("admm_dolfinx: r* lambda_max"):
            t0 = time.perf_counter()
            info = {}
            if method == "local":
                try:
                    lambda_max, info = lambda_max_multigrid(
                        space,
                        lambda_min,
                        tol,
                        max_it,
                        prefix,
                        multigrid,
                        # a floating body's: step 1's multigrid of A + r_a K
                        operator if isinstance(operator, IterativeOperator) else None,
                    )
                except NeedsFactorisation as reason:
                    logger.info("λ_max by factorisation instead of multigrid: %s", reason)
            if not info:
                lambda_max, info = lambda_max_factorised(
                    space, shared_operator(), lambda_min, tol, max_it, prefix, start
                )
            details.update(info, time_max=time.perf_counter() - t0)
    finally:
        start.destroy()
        space.destroy()
        if own_operator and operator is not None:
            operator.destroy()
    return lambda_min, lambda_max, details


def _finish(lambda_min, lambda_max, details, t_start) -> PenaltyEstimate:
    lambda_max = max(lambda_max, lambda_min)
    r = 1.0 / math.sqrt(lambda_min * lambda_max)
    estimate = PenaltyEstimate(
        r=r,
        lambda_min=lambda_min,
        lambda_max=lambda_max,
        solves=details["solves_min"] + details["solves_max"],
        time=time.perf_counter() - t_start,
        details=details,
    )
    how = (
        "exactly, from the dense pencil"
        if details.get("method") == "dense"
        else f"from {estimate.solves} solves"
    )
    logger.info(
        "r* = %.6g (λ_min %.4e, λ_max %.4e, κ %.3g) %s in %.3f s",
        r,
        lambda_min,
        lambda_max,
        estimate.condition_number,
        how,
        estimate.time,
    )
    return estimate
