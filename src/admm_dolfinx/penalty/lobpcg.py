"""The largest eigenpair of K x = θ B x without factorising B (LOBPCG + algebraic multigrid).

Used by the r* estimate for λ_max, whose eigenvector is the *smoothest* contact mode of
the whole body: a global quantity, so some global solver is unavoidable, but it need
not be a factorisation. LOBPCG (Knyazev's locally optimal block preconditioned
conjugate gradient, SLEPc ``EPSLOBPCG``) maximises the Rayleigh quotient xᵀKx / xᵀBx
with one smoothed-aggregation AMG V-cycle (PETSc ``PCGAMG``, with the rigid body
modes as near null space) per block vector and iteration, starting from the Ritz
vectors of the responses to a few trial loads (each from a few CG steps with the same
multigrid). Its Ritz value's error is
of the order of the squared residual over the gap to the next eigenvalue; with a
nearly multiple top eigenvalue (symmetric bodies) a loose residual test can stop
near the second one, so callers ask for a residual below their θ tolerance.

B must be symmetric positive definite and K symmetric positive semi-definite.
"""

from __future__ import annotations

import time

import numpy as np
from dolfinx import fem, la
from petsc4py import PETSc
from slepc4py import SLEPc

from admm_dolfinx.linalg.petsc import apply_options, solve_top_eigenpair

__all__ = ["BLOCK_SIZE", "gram_matrix", "largest_generalized_eigenpair", "rigid_body_modes"]

#: LOBPCG block size: two vectors resolve a nearly double top eigenvalue (symmetric
#: bodies) at the cost of two V-cycles per iteration (faster than 1 or 4 in
#: ``python benchmarks/penalty_cost.py``).
BLOCK_SIZE = 2
#: Multigrid-preconditioned CG steps per trial load for LOBPCG's start: a single
#: V-cycle per load leaves LOBPCG far from the top eigenvector on the 3D block on a
#: ball; four cut its iterations by about a factor of three, at three extra V-cycles
#: per load (``python benchmarks/penalty_cost.py``).
START_CG_STEPS = 4


def rigid_body_modes(V: fem.FunctionSpace) -> PETSc.NullSpace:
    """The rigid body motions of a P1 vector space, orthonormalised; collective.

    Args:
        V: Vector-valued space (2D: 3 modes, 3D: 6 modes).

    Returns:
        A PETSc null space object (the caller destroys it).
    """
    gdim = V.mesh.geometry.dim
    index_map, bs = V.dofmap.index_map, V.dofmap.index_map_bs
    n = index_map.size_local
    x = V.tabulate_dof_coordinates()[:n]
    rotations = [(0, 1)] if gdim == 2 else [(0, 1), (0, 2), (1, 2)]
    basis = [la.vector(index_map, bs=bs) for _ in range(gdim + len(rotations))]
    values = [b.array.reshape(-1, bs) for b in basis]
    for i in range(gdim):
        values[i][:n, i] = 1.0
    for k, (i, j) in enumerate(rotations):
        values[gdim + k][:n, i] = -x[:, j]
        values[gdim + k][:n, j] = x[:, i]
    la.orthonormalize(basis)
    vectors = [b.petsc_vec.copy() for b in basis]
    space = PETSc.NullSpace().create(vectors=vectors, comm=V.mesh.comm)
    for vec in vectors:
        vec.destroy()
    return space


class _ColumnByColumn:
    """A preconditioner applied to a block one column at a time.

    PETSc's blocked multigrid apply (``PCMatApply`` of ``PCGAMG``) crashes in parallel
    in PETSc 3.25; a Python PC without ``matApply`` makes SLEPc fall back to columns.
    """

    def __init__(self, pc: PETSc.PC):
        self.pc = pc

    def apply(self, pc: PETSc.PC, x: PETSc.Vec, y: PETSc.Vec) -> None:
        self.pc.apply(x, y)


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

    Returns:
        θ, the eigenvector (caller destroys it) and the iteration count.

    Raises:
        RuntimeError: If LOBPCG does not converge within ``max_it`` iterations.
    """
    eps = SLEPc.EPS().create(comm=B.getComm())
    multigrid = None
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
        multigrid = PETSc.PC().create(comm=B.getComm())
        multigrid.setOperators(B)
        multigrid.setType(PETSc.PC.Type.GAMG)
        apply_options(multigrid, prefix + "amg_", {})
        ksp = st.getKSP()
        ksp.setType(PETSc.KSP.Type.PREONLY)
        ksp.getPC().setType(PETSc.PC.Type.PYTHON)
        ksp.getPC().setPythonContext(_ColumnByColumn(multigrid))
        t0 = time.perf_counter()
        multigrid.setUp()
        setup_time = time.perf_counter() - t0
        start, cycles = [], 0
        if trial_loads:
            start, cycles = _ritz_start(K, B, multigrid, trial_loads, prefix)
        if info is not None:
            info["multigrid_setup"] = info.get("multigrid_setup", 0.0) + setup_time
            info["start_cycles"] = info.get("start_cycles", 0) + cycles
        theta, vec, its = solve_top_eigenpair(
            eps,
            B.createVecRight,
            f"LOBPCG did not converge to the largest eigenvalue of the contact pencil "
            f"within {max_it} iterations (tol {tol:g}). Loosen penalty_tol, give the "
            f"penalty explicitly, or tune the multigrid with -{prefix}amg_pc_gamg_* options",
            prefix=prefix,
            start=start,
            deflation=deflation or (),
        )
        return theta, vec, its
    finally:
        for v in start:
            v.destroy()
        eps.destroy()
        if multigrid is not None:
            multigrid.destroy()


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
        ksp.setPC(multigrid)
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
