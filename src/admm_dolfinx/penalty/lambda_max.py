"""λ_max, the large end of the contact pencil's spectrum (Koko 2019, §5), for r*.

λ_max comes from θ_max, the largest eigenvalue of K x = θ (A + r_a K) x, K = NᵀMN.
The eigenvalues are θ = λ / (1 + r_a λ), so λ = θ / (1 − r_a θ). A small auxiliary
r_a (r_a λ_max ≲ 1) keeps this map well conditioned while making A + r_a K positive
definite for floating bodies, whose rigid motions appear as θ = 1/r_a exactly
(λ = ∞): they are deflated, and do not enter r*, since no choice of r changes how
ADMM treats them. Its eigenvector is the *smoothest* contact mode, a global quantity,
so some global solver is unavoidable, but it need not be a factorisation:

* ``"local"`` (:func:`lambda_max_multigrid`): LOBPCG (Knyazev's locally optimal block
  preconditioned conjugate gradient, SLEPc ``EPSLOBPCG``) on the full-space pencil,
  maximising xᵀKx / xᵀBx, B = A + r_a K applied matrix-free, with one
  smoothed-aggregation AMG V-cycle of A (``PCGAMG``, with the rigid body modes that
  the problem attaches to A as near null space) per block vector and iteration. It
  starts from the Ritz vectors of the body's responses to affine normal pressures on Γ_C (a few
  multigrid-preconditioned CG steps each). No factorisation at all. Its Ritz value's
  error is of the order of the squared residual over the gap to the next eigenvalue,
  so the residual test is at the θ tolerance; with a nearly multiple top eigenvalue
  (symmetric bodies) it may stop nearer the second one, within the cluster's spread.
  A floating body (found when the problem was built:
  :mod:`admm_dolfinx.problem.rigid_motions`) has a singular A: on the multigrid path
  the V-cycle is step 1's, of A + r_a K, and the free rigid motions are deflated.
* ``"factorised"``, and for floating bodies off the multigrid path
  (:func:`lambda_max_factorised`): Krylov–Schur on M^{½} N (A + r_a K)⁻¹ Nᵀ M^{½}
  with a factorisation of A + r_a K (step 1's CG + GAMG solves on the multigrid path,
  where LOBPCG does not apply): exact to the tolerance, and independent of the
  partition to round-off.
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc
from slepc4py import SLEPc

from admm_dolfinx.linalg.contact_space import ContactSpace
from admm_dolfinx.linalg.petsc import (
    apply_options,
    prepare_eigensolve,
    top_eigenpair,
)
from admm_dolfinx.operators.penalised import IterativeOperator

__all__ = [
    "BLOCK_SIZE",
    "START_CG_STEPS",
    "NeedsFactorisation",
    "affine_pressure_loads",
    "gram_matrix",
    "lambda_max_factorised",
    "lambda_max_multigrid",
    "largest_generalized_eigenpair",
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
#: LOBPCG's residual tolerance relative to the eigenvalue tolerance. The Ritz value's
#: error is of the order of the squared residual over the gap to the next eigenvalue,
#: so a residual at tol leaves λ_max well within tol on every mesh of ``python
#: benchmarks/penalty_accuracy.py``; asking for half of it cost a third more
#: iterations on the 3D block for digits r does not need.
_MULTIGRID_TOL = 1.0
#: LOBPCG block size. With a nearly double top eigenvalue (symmetric bodies) a single
#: vector approaches the top eigenvector slowly, but its Rayleigh quotient is then
#: within the pair's small spread of λ_max, which is all r needs; a block of two
#: costs two V-cycles per iteration (``python benchmarks/penalty_accuracy.py``
#: measures λ_max against the dense pencil, on Example 3's symmetric block too).
BLOCK_SIZE = 1
#: Multigrid-preconditioned CG steps per trial load for LOBPCG's start. A single
#: V-cycle per load leaves LOBPCG far from the top eigenvector on the graded 3D block
#: on a ball (many more LOBPCG iterations); four take more V-cycles in all than two,
#: whose start LOBPCG finishes within a few iterations (``λ_max V-cycles`` of
#: ``python benchmarks/scale_3d.py`` counts the start's and LOBPCG's together).
START_CG_STEPS = 2
#: The relative residual of the Krylov solves with A + r_a K, where the operator is
#: iterative (a floating body on the multigrid path, where LOBPCG does not apply), as a
#: fraction of the eigenvalue
#: tolerance: each application of the compliance is then exact to far below what
#: the eigensolver resolves, and the rigid motions, where a CG error gathers, are
#: deflated. ``tests/admm/test_iterative_step1.py`` compares λ_max and r* with those of
#: the factorisation.
ITERATIVE_SOLVE_FACTOR = 1e-3
#: The tightest relative residual of those solves: a tighter one (a very small
#: ``penalty_tol``) would ask CG for digits that round-off takes, and stop it at its
#: iteration limit.
SOLVE_RTOL_FLOOR = 1e-12


class NeedsFactorisation(Exception):
    """The multigrid λ_max does not apply, or did not converge.

    It does not apply to a floating body without step 1's multigrid of A + r_a K.
    """


def _lambda_max_loop(
    lambda_min: float, top_eigenpair_at, rigid: list[PETSc.Vec]
) -> tuple[float, dict[str, Any]]:
    """λ_max = θ/(1 − r_a θ) from θ_max of K x = θ (A + r_a K) x, rigid motions deflated.

    Args:
        lambda_min: λ_min, to choose the first r_a.
        top_eigenpair_at: ``(r_a, deflation) -> (θ, vector, iterations)``; the vector
            is destroyed here.
        rigid: The rigid directions of the floating body's motions (known from the
            problem, :mod:`admm_dolfinx.problem.rigid_motions`), deflated: nothing is
            classified by the size of θ, which for a very compliant body (κ ≈ 1e10)
            would mistake its smoothest modes for rigid ones.

    Returns:
        λ_max and details (r_aux, rigid_modes, iterations of the last solve).
    """
    r_a = 1.0 / (_KAPPA_GUESS * lambda_min)
    for _attempt in range(8):
        theta, vec, its = top_eigenpair_at(r_a, rigid)
        vec.destroy()
        x = r_a * theta
        lambda_max = theta / (1.0 - x)
        if r_a * lambda_max <= _MAX_RA_LAMBDA:
            return lambda_max, {"r_aux": r_a, "rigid_modes": len(rigid), "restarts_max": its}
        r_a = 1.0 / lambda_max  # too large: the map θ → λ amplified errors
    raise RuntimeError(  # pragma: no cover - a pathological spectrum
        "could not separate λ_max from rigid motions"
    )


# ---------------------------------------------------------------------- factorised


class ComplianceOperator:
    """x ↦ M^{½} N (A + r_a K)⁻¹ Nᵀ M^{½} x  (eigenvalues θ = λ/(1 + r_a λ))."""

    def __init__(self, space: ContactSpace, operator):
        self.space = space
        self.operator = operator

    def mult(self, mat, x, y):
        """Apply y = M^{½} N (A + r_a K)⁻¹ Nᵀ M^{½} x (one substitution)."""
        s = self.space
        s.map.scatter(x.array_r, s.b, s.sqrt_mass)
        self.operator.solve(s.b, s.x)
        with y as out:
            out[:] = s.sqrt_mass * s.map.gather(s.x)


def lambda_max_factorised(
    space: ContactSpace,
    operator,
    lambda_min: float,
    tol: float,
    max_it: int,
    prefix: str,
    start: PETSc.Vec,
) -> tuple[float, dict[str, Any]]:
    """λ_max from Krylov–Schur on M^{½} N (A + r_a K)⁻¹ Nᵀ M^{½} (eigenvalues θ); collective.

    One numeric factorisation of A + r_a NᵀMN (per r_a tried) in the shared operator
    (a :class:`~admm_dolfinx.operators.penalised.PenalisedOperator`), one substitution
    per application; or, where that operator is iterative (step 1's multigrid, for a
    body too large to factorise), one Krylov solve to :data:`ITERATIVE_SOLVE_FACTOR`
    times ``tol`` (at least :data:`SOLVE_RTOL_FLOOR`) per application, its tolerance
    restored afterwards. The eigensolver reads options under ``{prefix}lmax_``.

    Raises:
        RuntimeError: If an iterative solve stopped at its iteration limit.
    """
    solves_before = operator.solves
    compliance = ComplianceOperator(space, operator)
    iterative = isinstance(operator, IterativeOperator)
    if iterative:
        rtol_before, unconverged_before = operator.rtol, operator.unconverged

    def top(r_a, rigid):
        operator.set_penalty(r_a)
        mat = space.shell(compliance)
        eps = space.krylov_schur(mat, tol / (1.0 + _MAX_RA_LAMBDA), max_it)
        try:
            prepare_eigensolve(eps, prefix=prefix + "lmax_", start=[start], deflation=rigid)
            eps.solve()
            return top_eigenpair(
                eps,
                f"SLEPc did not converge to the largest eigenvalue of the contact "
                f"compliance within {max_it} restarts (tol {tol:g}). Loosen penalty_tol "
                "or give the penalty explicitly",
            )
        finally:
            eps.destroy()
            mat.destroy()

    # the rigid directions M^½ N d of the floating motions, as distributed m-vectors
    rigid: list[PETSc.Vec] = []
    try:
        for motion in space.problem.rigid_motions.normal_motion:
            vec = space.create_vec()
            vec.array[:] = space.sqrt_mass * motion
            rigid.append(vec)
        if iterative:
            operator.set_tolerance(max(SOLVE_RTOL_FLOOR, ITERATIVE_SOLVE_FACTOR * tol))
        lambda_max, info = _lambda_max_loop(lambda_min, top, rigid)
    finally:
        for vec in rigid:
            vec.destroy()
        if iterative:
            operator.set_tolerance(rtol_before)
    if iterative and operator.unconverged > unconverged_before:  # the same on every rank
        raise RuntimeError(
            f"λ_max of r*: {operator.unconverged - unconverged_before} Krylov solve(s) with "
            "A + r_a NᵀMN stopped at their iteration limit. Loosen the eigenvalue "
            "tolerance (expert penalty_tol), check the step-1 options (ksp_max_it), or "
            "give the penalty explicitly."
        )
    info.update(solves_max=operator.solves - solves_before, lambda_max_method="factorised")
    return lambda_max, info


# ---------------------------------------------------------------------- multigrid


def affine_pressure_loads(space: ContactSpace) -> list[PETSc.Vec]:
    """Nodal forces Nᵀ M q for the normal pressures q = 1, x, y (, z) on Γ_C; collective.

    The smoothest contact modes (the top of the λ spectrum: uniform push, tilts) are
    close to the body's responses to these; LOBPCG starts from their Ritz vectors.
    The pressures are M-orthonormalised first and those that depend on the others on
    Γ_C are dropped (the height of a flat contact zone, or any combination constant
    on a plane): each kept load costs :data:`START_CG_STEPS` multigrid-preconditioned
    CG steps, and a dependent one would only be discarded by the Ritz step.
    """
    c, comm = space.problem.contact, space.comm
    coords = c.coordinates[:, : space.gdim]
    lower = np.empty(space.gdim)
    upper = np.empty(space.gdim)
    comm.Allreduce(coords.min(axis=0, initial=np.inf), lower, op=MPI.MIN)
    comm.Allreduce(coords.max(axis=0, initial=-np.inf), upper, op=MPI.MAX)
    centred = (coords - 0.5 * (lower + upper)) / np.maximum(upper - lower, 1e-300).max()
    # the centred coordinates are scaled to the largest extent of Γ_C, so the M-norm of
    # the constant pressure, sqrt|Γ_C|, is the size of every independent one
    size = math.sqrt(comm.allreduce(float(c.mass.sum()), op=MPI.SUM))
    kept: list[np.ndarray] = []
    for q in (np.ones(space.m_local), *centred.T):
        for basis in kept:  # modified Gram-Schmidt in the M inner product
            q = q - comm.allreduce(float(basis @ (c.mass * q)), op=MPI.SUM) * basis
        norm = math.sqrt(comm.allreduce(float(q @ (c.mass * q)), op=MPI.SUM))
        if norm > _DEPENDENT_PRESSURE * size:
            kept.append(q / norm)
    loads = []
    for q in kept:
        vec = space.create_full_vector()
        space.map.scatter(q, vec, c.mass)
        loads.append(vec)
    return loads


class _ColumnByColumn:
    """A preconditioner applied to a block one column at a time.

    PETSc's blocked multigrid apply (``PCMatApply`` of ``PCGAMG``) crashes in parallel
    in PETSc 3.25; a Python PC without ``matApply`` makes SLEPc fall back to columns.
    """

    def __init__(self, pc: PETSc.PC):
        self.pc = pc

    def apply(self, pc: PETSc.PC, x: PETSc.Vec, y: PETSc.Vec) -> None:
        self.pc.apply(x, y)


def gram_matrix(matrix: PETSc.Mat, vectors: list[PETSc.Vec]) -> np.ndarray:
    """G_ij = v_iᵀ M v_j (global inner products); collective."""
    work = matrix.createVecLeft()
    gram = np.empty((len(vectors), len(vectors)))
    for j, column in enumerate(vectors):
        matrix.mult(column, work)
        gram[:, j] = [row.dot(work) for row in vectors]
    work.destroy()
    return gram


def _ritz_start(K, B, multigrid, loads, prefix) -> tuple[list[PETSc.Vec], int]:
    """The top block-size Ritz vectors of (K, B) in span{B⁻¹ f_i}, and the V-cycles spent.

    Each B⁻¹ f_i is approximated by :data:`START_CG_STEPS` steps of conjugate gradients
    preconditioned by the multigrid (options under ``{prefix}start_``). Collective;
    global inner products only (Vec.dot), so the result is independent of the
    partition up to the multigrid's own dependence.
    """
    ksp = PETSc.KSP().create(comm=B.getComm())
    responses, cycles = [], 0
    try:
        ksp.setOptionsPrefix(prefix + "start_")
        ksp.setType(PETSc.KSP.Type.CG)
        ksp.setOperators(B)
        # the multigrid keeps its own operator (it may be step 1's, set up on A)
        ksp.getPC().setType(PETSc.PC.Type.PYTHON)
        ksp.getPC().setPythonContext(_ColumnByColumn(multigrid))
        ksp.setNormType(PETSc.KSP.NormType.NONE)  # a fixed number of steps
        ksp.setTolerances(max_it=START_CG_STEPS)
        ksp.setFromOptions()
        for load in loads:
            response = B.createVecRight()
            responses.append(response)
            ksp.solve(load, response)
            cycles += ksp.getIterationNumber()
            reason = ksp.getConvergedReason()  # DIVERGED_MAX_IT: the planned steps were taken
            if reason < 0 and reason != PETSc.KSP.ConvergedReason.DIVERGED_MAX_IT:
                # CG broke down (indefinite preconditioner, NaN): one V-cycle instead
                multigrid.apply(load, response)
                cycles += 1
    finally:
        ksp.destroy()
    gram_k, gram_b = gram_matrix(K, responses), gram_matrix(B, responses)
    # drop dependent responses (e.g. a load that vanishes on this Γ_C), then Ritz
    scale = np.sqrt(np.maximum(np.diag(gram_b), np.finfo(float).tiny))
    gram_k, gram_b = gram_k / np.outer(scale, scale), gram_b / np.outer(scale, scale)
    values, vectors = np.linalg.eigh(0.5 * (gram_b + gram_b.T))
    keep = values > 1e-10 * values.max()
    basis = vectors[:, keep] / np.sqrt(values[keep])
    reduced = basis.T @ (0.5 * (gram_k + gram_k.T)) @ basis
    ritz = basis @ np.linalg.eigh(reduced)[1][:, ::-1][:, :BLOCK_SIZE] / scale[:, None]
    start = []
    for coefficients in ritz.T:
        vec = B.createVecRight()
        vec.maxpy(coefficients, responses)
        start.append(vec)
    for response in responses:
        response.destroy()
    return start, cycles


def largest_generalized_eigenpair(
    K: PETSc.Mat,
    B: PETSc.Mat,
    *,
    tol: float,
    max_it: int,
    prefix: str,
    trial_loads: list[PETSc.Vec] | None = None,
    deflation: list[PETSc.Vec] | None = None,
    info: dict[str, float] | None = None,
    multigrid: PETSc.PC | None = None,
) -> tuple[float, PETSc.Vec, int]:
    """Largest θ with K x = θ B x, by LOBPCG preconditioned with AMG on B; collective.

    Args:
        K: Symmetric positive semi-definite matrix.
        B: Symmetric positive definite matrix; its near null space (rigid body modes)
            should be set for the multigrid.
        tol: Relative residual tolerance (SLEPc ``eps_tol``).
        max_it: Maximum LOBPCG iterations.
        prefix: Options prefix of the EPS; the multigrid (``PCGAMG``) reads options
            under ``{prefix}amg_``, the start's CG under ``{prefix}start_``.
        trial_loads: Right-hand sides f_i whose responses B⁻¹ f_i (approximated by a
            few multigrid-preconditioned CG steps) should contain the top eigenvector
            well; the best block-size combinations of them (Rayleigh–Ritz) start
            LOBPCG. Random vectors otherwise.
        deflation: Vectors whose B-orthogonal complement is searched.
        info: If given, the multigrid setup time (``"multigrid_setup"``, seconds) and
            the V-cycles spent on the start (``"start_cycles"``) are added to it.
        multigrid: A preconditioner set up already that approximates B⁻¹ up to a
            scalar factor (the iterative step 1's, on A, or on A + r_a K for a
            floating body; LOBPCG and the start's CG are invariant under that factor);
            borrowed, not destroyed. Built here on B otherwise (B must then be
            assembled).

    Returns:
        θ, the eigenvector (caller destroys it) and the iteration count.

    Raises:
        RuntimeError: If LOBPCG does not converge within ``max_it`` iterations.
    """
    eps = SLEPc.EPS().create(comm=B.getComm())
    own = None
    start: list[PETSc.Vec] = []
    try:
        eps.setOperators(K, B)
        eps.setProblemType(SLEPc.EPS.ProblemType.GHEP)
        eps.setType(SLEPc.EPS.Type.LOBPCG)
        eps.setWhichEigenpairs(SLEPc.EPS.Which.LARGEST_REAL)
        eps.setDimensions(nev=1)
        eps.setLOBPCGBlockSize(BLOCK_SIZE)
        eps.setTolerances(tol=tol, max_it=max_it)
        st = eps.getST()
        st.setType(SLEPc.ST.Type.PRECOND)
        st.setPreconditionerMat(B)  # precondition with B, not with K − σB
        t0 = time.perf_counter()
        if multigrid is None:
            multigrid = own = PETSc.PC().create(comm=B.getComm())
            own.setOperators(B)
            own.setType(PETSc.PC.Type.GAMG)
            apply_options(own, prefix + "amg_", {})
            own.setUp()
        setup_time = time.perf_counter() - t0
        ksp = st.getKSP()
        ksp.setType(PETSc.KSP.Type.PREONLY)
        ksp.getPC().setType(PETSc.PC.Type.PYTHON)
        ksp.getPC().setPythonContext(_ColumnByColumn(multigrid))
        cycles = 0
        if trial_loads:
            start, cycles = _ritz_start(K, B, multigrid, trial_loads, prefix)
        if info is not None:
            info["multigrid_setup"] = info.get("multigrid_setup", 0.0) + setup_time
            info["start_cycles"] = info.get("start_cycles", 0) + cycles
        prepare_eigensolve(eps, prefix=prefix, start=start, deflation=deflation or ())
        eps.solve()
        return top_eigenpair(
            eps,
            f"LOBPCG did not converge to the largest eigenvalue of the contact pencil "
            f"within {max_it} iterations (tol {tol:g}). Loosen penalty_tol, give the "
            f"penalty explicitly, or tune the multigrid with -{prefix}amg_pc_gamg_* options",
        )
    finally:
        for v in start:
            v.destroy()
        eps.destroy()
        if own is not None:
            own.destroy()


class _ShiftedStiffness:
    """x ↦ (A + r_a K) x / b_scale, matrix-free: no copy of A (a MATSHELL context).

    ``b_scale`` is the mean diagonal of A + r_a K, so that the operator has unit
    diagonal size whatever the units.
    """

    def __init__(self, A: PETSc.Mat, K: PETSc.Mat):
        self.A, self.K = A, K
        self.work = A.createVecLeft()
        self.diag_a, self.diag_k = A.getDiagonal(), K.getDiagonal()
        self.r_a, self.scale = 0.0, 1.0

    def matrix(self) -> PETSc.Mat:
        """A new MATSHELL applying this operator (caller destroys it); collective."""
        shell = PETSc.Mat().createPython(self.A.getSizes(), self, comm=self.A.getComm())
        shell.setOption(PETSc.Mat.Option.SYMMETRIC, True)
        shell.setOption(PETSc.Mat.Option.SPD, True)
        shell.setUp()
        return shell

    def set_shift(self, r_a: float) -> float:
        """Apply (A + r_a K)/b_scale from now on; returns b_scale; collective."""
        self.r_a = r_a
        self.work.waxpy(r_a, self.diag_k, self.diag_a)
        self.scale = self.work.sum() / self.work.getSize()
        return self.scale

    def mult(self, mat, x, y):
        """Apply y = (A + r_a K) x / b_scale."""
        self.A.mult(x, y)
        self.K.mult(x, self.work)
        y.axpy(self.r_a, self.work)
        y.scale(1.0 / self.scale)

    def getDiagonal(self, mat, d):
        """Set d = diag(A + r_a K) / b_scale (the MATSHELL interface)."""
        d.waxpy(self.r_a, self.diag_k, self.diag_a)
        d.scale(1.0 / self.scale)

    def free(self):
        """Free the work vectors."""
        for vec in (self.work, self.diag_a, self.diag_k):
            vec.destroy()


def lambda_max_multigrid(
    space: ContactSpace,
    lambda_min: float,
    tol: float,
    max_it: int,
    prefix: str,
    multigrid: PETSc.PC | None = None,
    operator: IterativeOperator | None = None,
) -> tuple[float, dict[str, Any]]:
    """λ_max from LOBPCG + AMG on the full-space pencil K x = θ (A + r_a K) x; collective.

    No factorisation, and no copy of A: A + r_a K is applied matrix-free. Each
    iteration costs one AMG V-cycle of A per block vector (A and A + r_a K are
    spectrally equivalent at the accepted r_a, for which r_a λ_max ≤
    :data:`_MAX_RA_LAMBDA`). The residual
    tolerance is tol (:data:`_MULTIGRID_TOL`). The multigrid aggregates depend on the
    partition, so r* does too, at the level of the eigenvalue error. The eigensolver
    reads options under ``{prefix}lmax_``. ``multigrid``: a multigrid of A set up
    already (the iterative step 1's, borrowed); otherwise one is set up here on A
    (options under ``{prefix}lmax_amg_``), once for every r_a tried.

    A floating body's A is singular, and its free rigid motions d_i are the pencil's
    top eigenvectors (θ = 1/r_a, λ = ∞): they are deflated (the search space is kept
    (A + r_a K)-orthogonal to them, and the start's loads orthogonal to them, so that
    their responses nearly so: the start's CG steps only approximate B⁻¹, and SLEPc
    removes the rest), and the preconditioner is the multigrid of A + r_a K of
    ``operator`` (step 1's on the multigrid path, set up at the first r_a tried and
    moved to the next; ``multigrid`` is not used). That set-up is then r*'s work:
    ``time_multigrid_setup`` counts it, and ``multigrid_shared`` is False.

    Raises:
        NeedsFactorisation: For a floating body without a multigrid ``operator``, or
            if LOBPCG did not converge.
    """
    problem = space.problem
    floating = problem.rigid_motions.floating > 0
    if floating and operator is None:
        raise NeedsFactorisation(
            "the body has a rigid motion (A is singular) and no multigrid of A + r_a K"
        )
    shifted = B = K_unit = own = None
    loads: list[PETSc.Vec] = []
    motions: list[PETSc.Vec] = []
    counts: dict[str, float] = {}
    try:
        shifted = _ShiftedStiffness(problem.A, problem.K)
        B = shifted.matrix()
        K_unit = problem.K.copy()
        diagonal = K_unit.getDiagonal()
        k_scale = diagonal.max()[1]
        diagonal.destroy()
        K_unit.scale(1.0 / k_scale)
        loads = affine_pressure_loads(space)
        if floating:
            # dᵢᵀf = 0 makes B⁻¹f B-orthogonal to dᵢ (the dᵢ are orthonormal): the start
            # stays near the complement, and SLEPc deflates what its CG steps leave
            motions = problem.rigid_motions.vectors(problem.V)
            for load in loads:
                for motion in motions:
                    load.axpy(-motion.dot(load) / motion.dot(motion), motion)
        elif multigrid is None:
            # one hierarchy on A for every r_a tried (spectrally equivalent to B)
            t0 = time.perf_counter()
            multigrid = own = PETSc.PC().create(comm=space.comm)
            own.setOperators(problem.A)  # carries the rigid body modes
            own.setType(PETSc.PC.Type.GAMG)
            try:
                apply_options(own, prefix + "lmax_amg_", {})
                own.setUp()
            except RuntimeError as error:  # as before: a factorisation instead
                raise NeedsFactorisation(f"the multigrid of A failed: {error}") from error
            counts["multigrid_setup"] = time.perf_counter() - t0
        iterations = 0

        def top(r_a, rigid):
            nonlocal iterations
            pc = multigrid
            if floating:
                assert operator is not None
                t0 = time.perf_counter()
                pc = operator.multigrid_at(r_a)
                counts["multigrid_setup"] = (
                    counts.get("multigrid_setup", 0.0) + time.perf_counter() - t0
                )
                if pc is None:
                    raise NeedsFactorisation("step 1's options chose no multigrid")
            # SLEPc's relative residual test is not invariant under scaling of K and B
            # separately: scale both to unit diagonal size, so that the iterations do
            # not depend on the units (E, lengths). θ = θ̃ k_scale / b_scale.
            b_scale = shifted.set_shift(r_a)
            theta, vec, its = largest_generalized_eigenpair(
                K_unit,
                B,
                tol=tol * _MULTIGRID_TOL,
                max_it=min(max_it, _MULTIGRID_MAX_IT),
                prefix=prefix + "lmax_",
                trial_loads=loads,
                deflation=rigid,
                info=counts,
                multigrid=pc,
            )
            iterations += its
            return theta * k_scale / b_scale, vec, its

        try:
            lambda_max, info = _lambda_max_loop(lambda_min, top, motions)
        except RuntimeError as error:  # LOBPCG did not converge
            raise NeedsFactorisation(str(error)) from error
    finally:
        for obj in (B, K_unit, own, *loads, *motions):
            if obj is not None:
                obj.destroy()
        if shifted is not None:
            shifted.free()
    info.update(
        solves_max=iterations * BLOCK_SIZE + int(counts.get("start_cycles", 0)),
        lobpcg_iterations=iterations,
        lambda_max_method="multigrid",
        time_multigrid_setup=counts.get("multigrid_setup", 0.0),
        # borrowed and set up by step 1 (Timings.factorization), not by r*; a floating
        # body's is step 1's too, but r* set it up (time_multigrid_setup)
        multigrid_shared=own is None and not floating,
    )
    return lambda_max, info
