"""The automatic penalty r* = 1/sqrt(λ_min λ_max) (Koko 2019, §4–5 and Algorithm 5).

ADMM contracts mode i of the dual error by |1 − rλ_i| / (1 + rλ_i), where λ_i are the
non-zero eigenvalues of A⁻¹NᵀMN, i.e. of the m × m pencil on the contact dofs

    M w = λ S w,     S = Schur complement of A onto the contact normal dofs,

so the best fixed r balances the two extremes: r* = 1/sqrt(λ_min λ_max).  Each
extreme is computed as the *largest* eigenvalue of a symmetric operator (the large
end converges in tens of applications; asking for the small end of the wrong
operator takes hundreds): an m × m one with SLEPc's Krylov–Schur, or, for λ_max at
the default tolerance, the full-space pencil with LOBPCG:

λ_min = 1 / μ_max,  μ_max = largest eigenvalue of M^{-½} S M^{-½}.
    S x is the reaction of the body when its contact normal displacements are
    prescribed to x: u = N_Fᵀ D⁻¹ x + w with w in ker N_F minimising the energy, found
    with one solve with Â = P A P + c N_FᵀN_F (P the nodal projector onto ker N_F,
    which rotates nothing explicitly; Â is A_II in rotated coordinates, plus c on the
    normal dofs). Then S x = D⁻¹ N_F A u.  Â is well posed even when A is singular
    (floating bodies), because every rigid motion of such a body moves Γ_C normally.

λ_max from θ_max, the largest eigenvalue of K x = θ (A + r_a K) x, K = NᵀMN.
    The eigenvalues are θ = λ / (1 + r_a λ), so λ = θ / (1 − r_a θ).  A small
    auxiliary r_a (r_a λ_max ≲ 1) keeps this map well conditioned while making
    A + r_a K positive definite for floating bodies, whose rigid motions appear as
    θ = 1/r_a exactly (λ = ∞): they are detected, deflated, and do not enter r*, since
    no choice of r changes how ADMM treats them.  Its eigenvector is the *smoothest*
    contact mode, a global quantity:

    * at the default (loose) tolerance, LOBPCG on the full-space pencil, preconditioned
      by one algebraic-multigrid V-cycle of A + r_a K per vector and iteration and
      started from the body's responses to affine normal pressures on Γ_C (four
      multigrid-preconditioned CG steps each)
      (:mod:`admm_dolfinx.preconditioned_eigen`): no factorisation at all;
    * at tolerances ≤ 1e-6, and for floating bodies (Rᵀ A R singular for the rigid
      body modes R: found with a few products before any solve), Krylov–Schur on
      M^{½} N (A + r_a K)⁻¹ Nᵀ M^{½} with a factorisation of A + r_a K: exact, and
      independent of the partition to round-off.

λ_min needs no factorisation of the whole body at the default (loose) tolerance: its
eigenvector is the shortest-wave contact mode, which lives within a few elements of
Γ_C, so S is replaced by the Schur complement S_L of a layer of L rings of cells
along Γ_C with the rest held fixed (S_L ≥ S, and S_L = S once the layer is the whole
mesh). L = 2, 4, 8, ... until μ_max settles to the tolerance; each layer costs a
factorisation of its own small Â. At tolerances ≤ 1e-6 the exact S is used.

Factorisations of the whole body: none at the default tolerance (the ADMM then
factorises A + r* NᵀMN once).  At tolerances ≤ 1e-6, Â and A + r_a NᵀMN, which have
A's sparsity pattern, are factorised in one
:class:`~admm_dolfinx.operators.PenalisedOperator` - the one the ADMM then
refactorises at r* - so the symbolic analysis (ordering) is computed once and each
costs one numeric factorisation.  :attr:`PenaltyEstimate.solves` counts operator
applications: substitutions with a factorisation, or AMG V-cycles.

Partition dependence: at tolerances ≤ 1e-6 r* is the same on any number of processes
to round-off (tested to 1e-6 under ``mpiexec -n 2``).  At the default tolerance the
multigrid aggregates depend on the partition, and r* with them, by about the
error of θ (a few 1e-5 measured; tested ≤ 2e-4 under ``mpiexec -n 2``);
the ADMM converges to the same solution.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from dolfinx.common import Timer
from mpi4py import MPI
from petsc4py import PETSc

from admm_dolfinx._logging import get_logger
from admm_dolfinx.contact_pencil import (
    ComplianceOperator,
    ContactSpace,
    LocalSolver,
    NodalMap,
    SchurOperator,
    contact_layer,
    largest_eigenvalue,
    mean_diagonal,
    projected_stiffness,
)
from admm_dolfinx.operators import PenalisedOperator
from admm_dolfinx.petsc import unique_prefix
from admm_dolfinx.preconditioned_eigen import (
    BLOCK_SIZE,
    gram_matrix,
    largest_generalized_eigenpair,
    rigid_body_modes,
)
from admm_dolfinx.problem import ContactProblem

__all__ = ["DEFAULT_PENALTY_TOL", "PenaltyEstimate", "estimate_penalty"]

logger = get_logger(__name__)

#: Default relative tolerance of the eigenvalue solves. r* needs a few digits only;
#: see the README for how little it moves r*.
DEFAULT_PENALTY_TOL = 1e-2

#: A guess of λ_max/λ_min used to pick the auxiliary r_a = 1/(κ_guess λ_min); if the
#: measured r_a λ_max is too large, r_a is lowered and λ_max recomputed.
_KAPPA_GUESS = 1e4
#: Accept r_a when r_a λ_max ≤ this (then λ = θ/(1 − r_aθ) amplifies errors ≤ 5x).
_MAX_RA_LAMBDA = 4.0
#: Above this eigenvalue tolerance λ_min comes from layers along Γ_C (no factorisation
#: of the whole body); at or below it, from the exact Schur complement.
_LOCAL_MAX_TOL = 1e-6
#: θ with 1 − r_a θ below this is a rigid motion (λ = ∞).
_RIGID_TOL = 1e-6
#: Rᵀ A R (rigid body modes R, orthonormal) below this × max diag(A): a floating body.
_FLOATING_TOL = 1e-10
#: A trial pressure whose part M-orthogonal to the previous ones is below this fraction
#: of sqrt|Γ_C| depends on them on Γ_C (round-off leaves ~1e-16) and is dropped.
_DEPENDENT_PRESSURE = 1e-8
#: LOBPCG iterations allowed before λ_max falls back to a factorisation.
_MULTIGRID_MAX_IT = 200
#: LOBPCG's residual tolerance relative to the eigenvalue tolerance. A residual test
#: at tol itself can stop inside a cluster of top eigenvalues (Example 3 level 2:
#: λ_max 1.1 % low at tol 1e-2); half of it keeps λ_max within 1e-3 on every measured
#: mesh (``benchmarks/penalty_accuracy.py``) at a third of the iterations of a tenth
#: (257k-dof Example 3, measured with one-V-cycle starts: 10 instead of 28).
_MULTIGRID_TOL = 0.5


@dataclass
class PenaltyEstimate:
    """Result of :func:`estimate_penalty`.

    Attributes:
        r: The penalty r* = 1/sqrt(λ_min λ_max).
        lambda_min: Smallest non-zero eigenvalue of A⁻¹NᵀMN.
        lambda_max: Largest finite eigenvalue of A⁻¹NᵀMN.
        solves: Linear solves (operator applications) used by both eigenvalue solves.
        time: Wall-clock seconds, factorisations included.
        details: Breakdown: solves and seconds per extreme (``solves_min``,
            ``time_min``, ``solves_max``, ``time_max``; ``time_multigrid_setup`` when
            λ_max came from multigrid), the auxiliary r_a, rigid modes deflated.
    """

    r: float
    lambda_min: float
    lambda_max: float
    solves: int
    time: float
    details: dict[str, Any] = field(default_factory=dict)

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

    @property
    def condition_number(self) -> float:
        """κ = λ_max / λ_min; the ADMM rate at r* is (√κ − 1)/(√κ + 1)."""
        return self.lambda_max / self.lambda_min


def _lambda_min_local(space, tol, max_it, start, prefix, options, vectors):
    """μ_max of the Schur complement of growing layers along Γ_C, until it settles.

    S_L (the rest of the body held fixed beyond L rings of cells) is stiffer than S
    and tends to it as L grows; its top eigenvector, the shortest-wave contact mode,
    lives within a few elements of Γ_C. L = 2, 4, 8, ... until two successive μ_max
    agree to ``tol`` or the layer is the whole mesh (then S_L = S exactly).
    """
    problem = space.problem
    bs = problem.V.dofmap.index_map_bs
    row0 = problem.A.getOwnershipRange()[0]
    previous, layers, solves, steps = None, 2, 0, 0
    while True:
        steps += 1
        nodes, whole = contact_layer(problem, layers)
        dofs = (row0 + nodes[:, None] * bs + np.arange(bs)[None, :]).ravel()
        index_set = PETSc.IS().createGeneral(dofs.astype(PETSc.IntType), comm=problem.comm)
        A_layer = problem.A.createSubMatrix(index_set, index_set)
        nodal = NodalMap(
            np.searchsorted(nodes, problem.contact.nodes),
            problem.contact.free_normals,
            bs,
            problem.gdim,
        )
        hat = projected_stiffness(A_layer, nodal)
        solver = LocalSolver(hat, prefix + "layer_", options)
        schur = SchurOperator(space, A_layer, nodal, solver)
        try:
            mu, vec, its = largest_eigenvalue(
                space, schur, prefix + "lmin_", tol, max_it, [], start
            )
        finally:
            solves += solver.solves
            schur.free()
            solver.destroy()
            for obj in (hat, A_layer, index_set):
                obj.destroy()
        vectors.append(vec)
        start = vec  # warm start the next, wider layer
        if whole or (previous is not None and abs(previous - mu) <= tol * mu):
            return mu, its, ("all" if whole else layers, steps), solves
        previous, layers = mu, 2 * layers


def _lambda_max_loop(lambda_min: float, top_eigenpair) -> tuple[float, dict[str, Any]]:
    """λ_max = θ/(1 − r_a θ) from θ_max of K x = θ (A + r_a K) x, deflating rigid motions.

    Args:
        lambda_min: λ_min, to choose the first r_a.
        top_eigenpair: ``(r_a, deflation) -> (θ, vector, iterations)``; the vector is
            kept (and destroyed here) when it is a rigid motion, destroyed otherwise.

    Returns:
        λ_max and details (r_aux, rigid_modes, iterations of the last solve).
    """
    r_a = 1.0 / (_KAPPA_GUESS * lambda_min)
    rigid: list[PETSc.Vec] = []
    try:
        for _attempt in range(8):
            theta, vec, its = top_eigenpair(r_a, rigid)
            x = r_a * theta
            if x > 1.0 - _RIGID_TOL:  # a rigid motion seen by Γ_C: deflate it
                rigid.append(vec)
                continue
            vec.destroy()
            lambda_max = theta / (1.0 - x)
            if r_a * lambda_max <= _MAX_RA_LAMBDA:
                return lambda_max, {"r_aux": r_a, "rigid_modes": len(rigid), "restarts_max": its}
            r_a = 1.0 / lambda_max  # too large: the map θ → λ amplified errors
        raise RuntimeError(  # pragma: no cover - needs > 6 rigid modes or a pathological spectrum
            "could not separate λ_max from rigid motions"
        )
    finally:
        for vec in rigid:
            vec.destroy()


def _lambda_max_factorised(space, operator, lambda_min, tol, max_it, prefix, start):
    """λ_max from Krylov–Schur on M^{½} N (A + r_a K)⁻¹ Nᵀ M^{½} (eigenvalues θ).

    One numeric factorisation of A + r_a NᵀMN (per r_a tried) in the shared operator,
    one substitution per application: exact to the eigenvalue tolerance and
    independent of the partition to round-off.
    """
    solves_before = operator.solves

    def top(r_a, rigid):
        operator.set_penalty(r_a)
        return largest_eigenvalue(
            space,
            ComplianceOperator(space, operator),
            prefix + "lmax_",
            tol / (1.0 + _MAX_RA_LAMBDA),
            max_it,
            rigid,
            start,
        )

    lambda_max, info = _lambda_max_loop(lambda_min, top)
    info.update(solves_max=operator.solves - solves_before, lambda_max_method="factorised")
    return lambda_max, info


def _has_rigid_motion(A: PETSc.Mat, modes: PETSc.NullSpace) -> bool:
    """Whether a combination of the rigid body modes R costs no energy: Rᵀ A R singular.

    A rigid motion that moves a Dirichlet dof strains the elements there (energy of
    order E/n for orthonormal R and n dofs); a free one costs round-off (≈ 1e-16 E).
    The threshold 1e-10 × max diag(A) separates the two for any practical n. Collective.
    """
    gram = gram_matrix(A, modes.getVecs())
    scale = A.getDiagonal()
    largest = scale.max()[1]
    scale.destroy()
    eigenvalues = np.linalg.eigvalsh(0.5 * (gram + gram.T))
    return bool(eigenvalues[0] <= _FLOATING_TOL * largest)


def _affine_pressure_loads(space: ContactSpace) -> list[PETSc.Vec]:
    """Nodal forces Nᵀ M q for the normal pressures q = 1, x, y (, z) on Γ_C; collective.

    The smoothest contact modes (the top of the λ spectrum: uniform push, tilts) are
    close to the body's responses to these; LOBPCG starts from their Ritz vectors.
    The pressures are M-orthonormalised first and those that depend on the others on
    Γ_C are dropped (the height of a flat contact zone, or any combination constant
    on a plane): each kept load costs START_CG_STEPS multigrid-preconditioned
    CG steps, and a dependent one would only be discarded by the Ritz step.
    """
    problem, c = space.problem, space.problem.contact
    coords = c.coordinates[:, : problem.gdim]
    lower = np.empty(problem.gdim)
    upper = np.empty(problem.gdim)
    problem.comm.Allreduce(coords.min(axis=0, initial=np.inf), lower, op=MPI.MIN)
    problem.comm.Allreduce(coords.max(axis=0, initial=-np.inf), upper, op=MPI.MAX)
    centred = (coords - 0.5 * (lower + upper)) / np.maximum(upper - lower, 1e-300).max()
    # the centred coordinates are scaled to the largest extent of Γ_C, so the M-norm of
    # the constant pressure, sqrt|Γ_C|, is the size of every independent one
    size = math.sqrt(problem.comm.allreduce(float(c.mass.sum()), op=MPI.SUM))
    kept: list[np.ndarray] = []
    for q in (np.ones(space.m_local), *centred.T):
        for basis in kept:  # modified Gram-Schmidt in the M inner product
            q = q - problem.comm.allreduce(float(basis @ (c.mass * q)), op=MPI.SUM) * basis
        norm = math.sqrt(problem.comm.allreduce(float(q @ (c.mass * q)), op=MPI.SUM))
        if norm > _DEPENDENT_PRESSURE * size:
            kept.append(q / norm)
    loads = []
    for q in kept:
        vec = problem.create_vector()
        space.map.scatter(q, vec, c.mass)
        loads.append(vec)
    return loads


class _NeedsFactorisation(Exception):
    """The multigrid λ_max does not apply (floating body) or did not converge."""


def _lambda_max_multigrid(space, lambda_min, tol, max_it, prefix):
    """λ_max from LOBPCG + AMG on the full-space pencil K x = θ (A + r_a K) x.

    No factorisation: each iteration costs one AMG V-cycle per block vector. The
    residual tolerance is tol/2. The multigrid aggregates depend on the partition,
    so r* does too, at the level of the eigenvalue error.
    """
    problem = space.problem
    modes = rigid_body_modes(problem.V)
    if _has_rigid_motion(problem.A, modes):
        modes.destroy()
        raise _NeedsFactorisation("the body has a rigid motion (A is singular)")
    B = problem.A.duplicate(copy=True)
    B.setOption(PETSc.Mat.Option.SPD, True)
    B.setNearNullSpace(modes)
    K_unit = problem.K.copy()
    diagonal = K_unit.getDiagonal()
    k_scale = diagonal.max()[1]
    diagonal.destroy()
    K_unit.scale(1.0 / k_scale)
    loads = _affine_pressure_loads(space)
    iterations = 0
    counts: dict[str, float] = {}

    def top(r_a, rigid):
        nonlocal iterations
        if rigid:  # a rigid motion _has_rigid_motion missed: the factorised path deflates it
            raise _NeedsFactorisation("Γ_C sees a rigid motion of the body")
        problem.A.copy(B, structure=PETSc.Mat.Structure.SAME_NONZERO_PATTERN)
        B.axpy(r_a, problem.K, structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN)
        # SLEPc's relative residual test is not invariant under scaling of K and B
        # separately: scale both to unit diagonal size, so that the iterations do not
        # depend on the units (E, lengths). θ = θ̃ k_scale / b_scale.
        b_scale = mean_diagonal(B)
        B.scale(1.0 / b_scale)
        theta, vec, its = largest_generalized_eigenpair(
            K_unit,
            B,
            tol=tol * _MULTIGRID_TOL,
            max_it=min(max_it, _MULTIGRID_MAX_IT),
            prefix=prefix + "lmax_",
            trial_loads=loads,
            info=counts,
        )
        iterations += its
        return theta * k_scale / b_scale, vec, its

    try:
        lambda_max, info = _lambda_max_loop(lambda_min, top)
    except RuntimeError as error:  # LOBPCG did not converge
        raise _NeedsFactorisation(str(error)) from error
    finally:
        for obj in (B, K_unit, modes, *loads):
            obj.destroy()
    info.update(
        solves_max=iterations * BLOCK_SIZE + int(counts.get("start_cycles", 0)),
        lobpcg_iterations=iterations,
        lambda_max_method="multigrid",
        time_multigrid_setup=counts.get("multigrid_setup", 0.0),
    )
    return lambda_max, info


def estimate_penalty(
    problem: ContactProblem,
    *,
    tol: float = DEFAULT_PENALTY_TOL,
    max_it: int = 500,
    operator: PenalisedOperator | None = None,
    petsc_options: dict | None = None,
    petsc_options_prefix: str | None = None,
) -> PenaltyEstimate:
    """Compute r* = 1/sqrt(λ_min λ_max) with SLEPc on the contact dofs; collective.

    Args:
        problem: The contact problem.
        tol: Relative tolerance of both eigenvalue solves (SLEPc ``eps_tol``).
        max_it: Maximum Krylov–Schur restarts.
        operator: A :class:`PenalisedOperator` to use (and leave factorised at r_a), so
            that the ADMM reuses its symbolic factorisation; a private one otherwise.
        petsc_options: Options of the factorisations (MUMPS Cholesky by default).
        petsc_options_prefix: Prefix; sub-objects get ``schur_``, ``lmin_``, ``lmax_``.

    Returns:
        The estimate.

    Raises:
        ValueError: For a tolerance outside (0, 1).
        RuntimeError: If an eigenvalue solve does not converge.
    """
    if not (0.0 < tol < 1.0):
        raise ValueError(f"tol must lie in (0, 1), got {tol}.")
    prefix = petsc_options_prefix or unique_prefix("penalty_")
    t_start = time.perf_counter()
    space = ContactSpace(problem)
    own_operator = operator is None
    if operator is None:
        operator = PenalisedOperator(problem, prefix, petsc_options)
    schur = None
    vectors: list[PETSc.Vec] = []
    details: dict[str, Any] = {"tol": tol, "m": space.m}
    try:
        # ---- λ_min = 1 / μ_max(M^{-½} S M^{-½})
        with Timer("admm_dolfinx: r* lambda_min"):
            t0 = time.perf_counter()
            start = space.start_vector()
            vectors.append(start)
            if tol > _LOCAL_MAX_TOL:
                mu, its, layers, local_solves = _lambda_min_local(
                    space, tol, max_it, start, prefix, petsc_options, vectors
                )
                details.update(layers=layers[0], layer_steps=layers[1], solves_min=local_solves)
            else:
                hat = projected_stiffness(problem.A, space.map)
                operator.load(hat, "the projected stiffness P A P + c NᵀN (Schur complement)")
                hat.destroy()
                schur = SchurOperator(space, problem.A, space.map, operator)
                mu, vec, its = largest_eigenvalue(
                    space, schur, prefix + "lmin_", tol, max_it, [], start
                )
                vectors.append(vec)
                details.update(layers="all", layer_steps=0, solves_min=operator.solves)
            lambda_min = 1.0 / mu
            details.update(time_min=time.perf_counter() - t0, restarts_min=its)

        # ---- λ_max from θ_max, the largest eigenvalue of K x = θ (A + r_a K) x
        with Timer("admm_dolfinx: r* lambda_max"):
            t0 = time.perf_counter()
            info = None
            if tol > _LOCAL_MAX_TOL:
                try:
                    lambda_max, info = _lambda_max_multigrid(space, lambda_min, tol, max_it, prefix)
                except _NeedsFactorisation as reason:
                    logger.info("λ_max by factorisation instead of multigrid: %s", reason)
            if info is None:
                lambda_max, info = _lambda_max_factorised(
                    space, operator, lambda_min, tol, max_it, prefix, start
                )
            details.update(info, time_max=time.perf_counter() - t0)
    finally:
        if schur is not None:
            schur.free()
        for vec in vectors:
            vec.destroy()
        space.destroy()
        if own_operator:
            operator.destroy()

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
    logger.info(
        "r* = %.6g (λ_min %.4e, λ_max %.4e, κ %.3g) from %d solves in %.3f s",
        r,
        lambda_min,
        lambda_max,
        estimate.condition_number,
        estimate.solves,
        estimate.time,
    )
    return estimate
