"""The two ends of the contact pencil's spectrum, λ_min and λ_max, for r* (Koko 2019, §5).

Both are computed as the *largest* eigenvalue of a symmetric operator (the large end
converges in tens of applications; the small end of the wrong operator in hundreds).

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
      (:mod:`admm_dolfinx.penalty.lobpcg`): no factorisation at all;
    * at tolerances ≤ 1e-6, and for floating bodies (found when the problem was built:
      :mod:`admm_dolfinx.problem.rigid_motions`), Krylov–Schur on
      M^{½} N (A + r_a K)⁻¹ Nᵀ M^{½} with a factorisation of A + r_a K: exact, and
      independent of the partition to round-off.

λ_min needs no factorisation of the whole body at the default (loose) tolerance: its
eigenvector is the shortest-wave contact mode, which lives within a few elements of
Γ_C, so S is replaced by the Schur complement S_L of a layer of L rings of cells
along Γ_C with the rest held fixed (S_L ≥ S, and S_L = S once the layer is the whole
mesh). L = 2, 4, 8, ... until μ_max settles to the tolerance; each layer costs a
factorisation of its own small Â. At tolerances ≤ 1e-6 the exact S is used.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from typing import Any

import numpy as np
from dolfinx.common import Timer
from mpi4py import MPI
from petsc4py import PETSc

from admm_dolfinx._logging import get_logger
from admm_dolfinx.linalg.operators import PenalisedOperator
from admm_dolfinx.penalty.contact_operators import (
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
from admm_dolfinx.penalty.lobpcg import (
    BLOCK_SIZE,
    largest_generalized_eigenpair,
    rigid_body_modes,
)
from admm_dolfinx.problem.contact_problem import ContactProblem

logger = get_logger(__name__)

__all__ = [
    "NeedsFactorisation",
    "affine_pressure_loads",
    "lambda_max_factorised",
    "lambda_max_multigrid",
    "lambda_min_from_layers",
]

#: A guess of λ_max/λ_min used to pick the auxiliary r_a = 1/(κ_guess λ_min); if the
#: measured r_a λ_max is too large, r_a is lowered and λ_max recomputed.
_KAPPA_GUESS = 1e4
#: Accept r_a when r_a λ_max ≤ this (then λ = θ/(1 − r_aθ) amplifies errors ≤ 5×).
_MAX_RA_LAMBDA = 4.0
#: A trial pressure whose part M-orthogonal to the previous ones is below this fraction
#: of sqrt|Γ_C| depends on them on Γ_C (round-off leaves ~1e-16) and is dropped.
_DEPENDENT_PRESSURE = 1e-8
#: LOBPCG iterations allowed before λ_max falls back to a factorisation.
_MULTIGRID_MAX_IT = 200
#: LOBPCG's residual tolerance relative to the eigenvalue tolerance. A residual test
#: at tol itself can stop inside a cluster of top eigenvalues; half of it keeps λ_max
#: well within tol on every mesh of ``python benchmarks/penalty_accuracy.py``, at far
#: fewer iterations than a tenth.
_MULTIGRID_TOL = 0.5


def lambda_min_from_layers(space, tol, max_it, start, prefix, options, vectors):
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
        nodal = NodalMap(
            np.searchsorted(nodes, problem.contact.nodes),
            problem.contact.free_normals,
            bs,
            problem.gdim,
        )
        index_set = A_layer = hat = solver = schur = None
        try:
            index_set = PETSc.IS().createGeneral(dofs.astype(PETSc.IntType), comm=problem.comm)
            A_layer = problem.A.createSubMatrix(index_set, index_set)
            hat = projected_stiffness(A_layer, nodal)
            solver = LocalSolver(hat, prefix + "layer_", options)
            schur = SchurOperator(space, A_layer, nodal, solver)
            mu, vec, its = largest_eigenvalue(
                space, schur, prefix + "lmin_", tol, max_it, [], start
            )
        finally:
            if solver is not None:
                solves += solver.solves
                solver.destroy()
            if schur is not None:
                schur.free()
            for obj in (hat, A_layer, index_set):
                if obj is not None:
                    obj.destroy()
        vectors.append(vec)
        start = vec  # warm start the next, wider layer
        if whole or (previous is not None and abs(previous - mu) <= tol * mu):
            return mu, its, ("all" if whole else layers, steps), solves
        previous, layers = mu, 2 * layers


def _lambda_max_loop(
    lambda_min: float, top_eigenpair, rigid: list[PETSc.Vec]
) -> tuple[float, dict[str, Any]]:
    """λ_max = θ/(1 − r_a θ) from θ_max of K x = θ (A + r_a K) x, rigid motions deflated.

    Args:
        lambda_min: λ_min, to choose the first r_a.
        top_eigenpair: ``(r_a, deflation) -> (θ, vector, iterations)``; the caller's
            vector is destroyed here.
        rigid: The rigid directions of the floating body's motions (known from the
            problem, :mod:`admm_dolfinx.problem.rigid_motions`), deflated: nothing is
            classified by the size of θ, which for a very compliant body (κ ≈ 1e10)
            would mistake its smoothest modes for rigid ones.

    Returns:
        λ_max and details (r_aux, rigid_modes, iterations of the last solve).
    """
    r_a = 1.0 / (_KAPPA_GUESS * lambda_min)
    for _attempt in range(8):
        theta, vec, its = top_eigenpair(r_a, rigid)
        vec.destroy()
        x = r_a * theta
        lambda_max = theta / (1.0 - x)
        if r_a * lambda_max <= _MAX_RA_LAMBDA:
            return lambda_max, {"r_aux": r_a, "rigid_modes": len(rigid), "restarts_max": its}
        r_a = 1.0 / lambda_max  # too large: the map θ → λ amplified errors
    raise RuntimeError(  # pragma: no cover - a pathological spectrum
        "could not separate λ_max from rigid motions"
    )


def _rigid_directions(space: ContactSpace) -> list[PETSc.Vec]:
    """M^½ N d of the floating motions d, as distributed m-vectors (caller destroys)."""
    problem = space.problem
    vectors = []
    for motion in problem.rigid_motions.normal_motion:
        vec = space.create_vec()
        vec.array[:] = space.sqrt_mass * motion
        vectors.append(vec)
    return vectors


def lambda_max_factorised(space, operator, lambda_min, tol, max_it, prefix, start):
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

    rigid = _rigid_directions(space)
    try:
        lambda_max, info = _lambda_max_loop(lambda_min, top, rigid)
    finally:
        for vec in rigid:
            vec.destroy()
    info.update(solves_max=operator.solves - solves_before, lambda_max_method="factorised")
    return lambda_max, info


def affine_pressure_loads(space: ContactSpace) -> list[PETSc.Vec]:
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


class NeedsFactorisation(Exception):
    """The multigrid λ_max does not apply (floating body) or did not converge."""


def lambda_max_multigrid(
    space: ContactSpace, lambda_min: float, tol: float, max_it: int, prefix: str
) -> tuple[float, dict[str, Any]]:
    """λ_max from LOBPCG + AMG on the full-space pencil K x = θ (A + r_a K) x.

    No factorisation: each iteration costs one AMG V-cycle per block vector. The
    residual tolerance is tol/2. The multigrid aggregates depend on the partition,
    so r* does too, at the level of the eigenvalue error.
    """
    problem = space.problem
    if problem.rigid_motions.floating:
        raise NeedsFactorisation("the body has a rigid motion (A is singular)")
    modes = rigid_body_modes(problem.V)
    B = problem.A.duplicate(copy=True)
    K_unit = problem.K.copy()
    loads: list[PETSc.Vec] = []
    try:
        B.setOption(PETSc.Mat.Option.SPD, True)
        B.setNearNullSpace(modes)
        diagonal = K_unit.getDiagonal()
        k_scale = diagonal.max()[1]
        diagonal.destroy()
        K_unit.scale(1.0 / k_scale)
        loads = affine_pressure_loads(space)
    except BaseException:
        for obj in (B, K_unit, modes, *loads):
            obj.destroy()
        raise
    iterations = 0
    counts: dict[str, float] = {}

    def top(r_a, rigid):
        nonlocal iterations
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
        lambda_max, info = _lambda_max_loop(lambda_min, top, [])
    except RuntimeError as error:  # LOBPCG did not converge
        raise NeedsFactorisation(str(error)) from error
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


def iterative_extremes(
    problem: ContactProblem,
    method: str,
    tol: float,
    max_it: int,
    operator: PenalisedOperator | None,
    prefix: str,
    petsc_options: Mapping[str, Any] | None,
) -> tuple[float, float, dict[str, Any]]:
    """λ_min, λ_max and details by the ``"local"`` or ``"factorised"`` method; collective.

    Args:
        problem: The contact problem.
        method: ``"local"`` (layers and multigrid) or ``"factorised"``.
        tol: Eigenvalue tolerance.
        max_it: Krylov–Schur restarts.
        operator: A :class:`~admm_dolfinx.linalg.operators.PenalisedOperator` to share
            factorisations with (None: a private one).
        prefix: Options prefix of the eigensolvers and factorisations.
        petsc_options: Options of the factorisations.
    """
    space = ContactSpace(problem)
    own_operator = operator is None
    if operator is None:
        operator = PenalisedOperator(problem, prefix, petsc_options)
    schur = None
    vectors: list[PETSc.Vec] = []
    local = method == "local"
    details: dict[str, Any] = {"method": method, "tol": tol, "m": space.m}
    try:
        # ---- λ_min = 1 / μ_max(M^{-½} S M^{-½})
        with Timer("admm_dolfinx: r* lambda_min"):
            t0 = time.perf_counter()
            start = space.start_vector()
            vectors.append(start)
            if local:
                mu, its, layers, local_solves = lambda_min_from_layers(
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
            if local:
                try:
                    lambda_max, info = lambda_max_multigrid(space, lambda_min, tol, max_it, prefix)
                except NeedsFactorisation as reason:
                    logger.info("λ_max by factorisation instead of multigrid: %s", reason)
            if info is None:
                lambda_max, info = lambda_max_factorised(
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

    return lambda_min, lambda_max, details
