"""Reference solvers for the same discrete contact problem (for tests and benchmarks).

Both are independent of the ADMM code path and solve the QP of
:class:`~admm_dolfinx.ContactProblem` (minimise ½uᵀAu − fᵀu subject to N u ≤ g):

* :func:`solve_snes_vi`: a variational inequality with PETSc's semismooth active-set
  Newton method (``vinewtonrsls``) and a MUMPS factorisation of the reduced Jacobian;
  exact up to round-off once the active set is found, distributed. PETSc's VI solvers
  take *bounds* on the unknowns, so it applies where every contact direction (row of
  N) is along a coordinate axis: any body on a plane parallel to a coordinate plane
  with the default ``contact_normal="obstacle"`` (curved bodies included), and flat
  contact faces parallel to it in the paper's model. It raises otherwise.
* :func:`solve_osqp`: OSQP (an ADMM for general QPs, with its own factorisation and
  solution polishing) at a tight tolerance on the extracted QP, for any obstacle
  (a tilted plane, a ball); one process.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
from dolfinx import fem
from mpi4py import MPI
from petsc4py import PETSc

from admm_dolfinx.linalg.petsc import prefixed_options, unique_prefix
from admm_dolfinx.problem.contact_problem import ContactProblem
from admm_dolfinx.problem.kkt import KKTResiduals, compute_kkt_residuals

__all__ = ["BaselineResult", "ExtractedQP", "extract_qp", "solve_osqp", "solve_snes_vi"]

_AXIS_TOL = 1e-12


@dataclass
class BaselineResult:
    """Solution of a reference solver.

    Attributes:
        u: Displacement Function.
        pressure: Contact pressure λ as a P1 scalar Function.
        multiplier: λ at the owned contact nodes.
        iterations: Newton iterations.
        kkt: Relative KKT residuals.
        time: Wall-clock seconds of the solve.
    """

    u: fem.Function
    pressure: fem.Function
    multiplier: npt.NDArray[np.float64]
    iterations: int
    kkt: KKTResiduals
    time: float


def _axis_bounds(problem: ContactProblem, lower: PETSc.Vec, upper: PETSc.Vec) -> None:
    c = problem.contact
    normals = c.normals
    axis = np.argmax(np.abs(normals), axis=1)
    sign = np.sign(normals[np.arange(normals.shape[0]), axis])
    off_axis = np.abs(normals).sum(axis=1) - np.abs(sign)
    aligned = np.all(np.abs(off_axis) <= _AXIS_TOL)
    if not problem.comm.allreduce(bool(aligned), op=MPI.LAND):
        raise ValueError(
            "The SNES VI baseline needs axis-aligned contact normals (bound constraints); "
            "this problem has curved or tilted contact. Use the ADMM solver, or compare "
            "with the KKT residuals instead."
        )
    bs = problem.V.dofmap.index_map_bs
    lower.set(PETSc.NINFINITY)
    upper.set(PETSc.INFINITY)
    with lower as lo, upper as up:
        lo2, up2 = lo.reshape(-1, bs), up.reshape(-1, bs)
        pos = sign > 0
        up2[c.nodes[pos], axis[pos]] = c.gap[pos]
        lo2[c.nodes[~pos], axis[~pos]] = -c.gap[~pos]


def solve_snes_vi(
    problem: ContactProblem,
    *,
    tol: float = 1e-10,
    max_iter: int = 200,
    petsc_options: Mapping[str, Any] | None = None,
    petsc_options_prefix: str | None = None,
    initial_guess: PETSc.Vec | None = None,
) -> BaselineResult:
    """Solve the contact QP with PETSc SNES ``vinewtonrsls`` (active-set Newton) + MUMPS.

    Args:
        problem: A contact problem whose contact normals are axis-aligned.
        tol: SNES relative tolerances: residual (also absolute, scaled by ‖f‖) and
            Newton step length relative to ‖u‖.
        max_iter: Maximum Newton iterations.
        petsc_options: Extra SNES/KSP options under the prefix.
        petsc_options_prefix: Options prefix; unique by default.
        initial_guess: Start from this displacement (e.g. an ADMM solution: Newton
            then only confirms its active set); zero by default.

    Returns:
        The reference solution.

    Raises:
        ValueError: If the normals are not axis-aligned.
        RuntimeError: If SNES does not converge.
    """
    prefix = petsc_options_prefix or unique_prefix("snesvi_")
    A = problem.A
    load = problem.load_vector()
    scale = load.norm() or 1.0
    u = fem.Function(problem.V, name="displacement")
    x = u.x.petsc_vec
    F = problem.create_vector()
    lower, upper = problem.create_vector(), problem.create_vector()
    snes = PETSc.SNES().create(problem.comm)
    try:
        _axis_bounds(problem, lower, upper)

        def residual(_snes, xk, Fk):
            A.mult(xk, Fk)
            Fk.axpy(-1.0, load)

        snes.setFunction(residual, F)
        snes.setJacobian(lambda *_: None, A, A)
        snes.setVariableBounds(lower, upper)
        options = {
            "snes_type": "vinewtonrsls",
            "snes_rtol": tol,
            "snes_atol": tol * scale,
            # Once the active set is right the (linear) Newton step is round-off: stop on
            # the step length, which is scale-free and immune to the residual's floor.
            "snes_stol": tol,
            "snes_max_it": max_iter,
            "snes_linesearch_type": "basic",
            "ksp_type": "preonly",
            "pc_type": "lu",
            "pc_factor_mat_solver_type": "mumps",
            **dict(petsc_options or {}),
        }
        if initial_guess is None:
            x.set(0.0)
        else:
            initial_guess.copy(x)
        snes.setOptionsPrefix(prefix)
        # the reduced systems are factorised inside the solve: keep the options until then
        with prefixed_options(prefix, options):
            snes.setFromOptions()
            t0 = time.perf_counter()
            snes.solve(None, x)
            elapsed = time.perf_counter() - t0
        reason = snes.getConvergedReason()
        if reason <= 0:
            raise RuntimeError(f"SNES VI did not converge (reason {reason}).")
        u.x.scatter_forward()
        A.mult(x, F)
        F.aypx(-1.0, load)  # F = f − A u = NᵀMλ on the free dofs
        lam = problem.multiplier_from_residual(F)
        kkt = compute_kkt_residuals(problem, x, lam)
        return BaselineResult(
            u=u,
            pressure=problem.pressure_function(lam),
            multiplier=lam,
            iterations=snes.getIterationNumber(),
            kkt=kkt,
            time=elapsed,
        )
    finally:
        snes.destroy()
        for vec in (F, lower, upper):
            vec.destroy()


@dataclass
class ExtractedQP:
    """The contact QP on the free dofs, as SciPy matrices (one process).

    minimise ½ xᵀP x + qᵀx subject to C x ≤ upper, with x the free dofs of u and
    u = u_D on the Dirichlet dofs; C = M^{½} N (rows scaled by the lumped mass).

    Attributes:
        P: A on the free dofs (CSC).
        q: −f on the free dofs.
        C: M^{½} N on the free dofs (CSC).
        upper: M^{½} (g − N u_D); +inf where a node can never touch.
        free: Indices of the free dofs.
        u_d: The Dirichlet values (zero on free dofs), length n.
    """

    P: Any
    q: npt.NDArray[np.float64]
    C: Any
    upper: npt.NDArray[np.float64]
    free: npt.NDArray[np.int64]
    u_d: npt.NDArray[np.float64]


def extract_qp(problem: ContactProblem) -> ExtractedQP:
    """The problem's QP as SciPy matrices; one process (``COMM_SELF``).

    Raises:
        ValueError: Under MPI.
    """
    import scipy.sparse as sp
    from dolfinx.fem import petsc as fem_petsc

    if problem.comm.size > 1:
        raise ValueError("extract_qp gathers nothing: build the problem on COMM_SELF.")
    c = problem.contact
    bs = problem.V.dofmap.index_map_bs
    n = problem.A.getSize()[0]
    fixed = np.zeros(n, dtype=bool)
    for bc in problem.bcs:
        fixed[bc.dof_indices()[0]] = True
    free = np.flatnonzero(~fixed)
    indptr, indices, data = problem.A.getValuesCSR()
    A = sp.csr_matrix((data, indices, indptr), shape=problem.A.getSize())
    values = problem.create_vector()
    values.set(0.0)
    fem_petsc.set_bc(values, problem.bcs)
    u_d = values.array_r.copy()
    values.destroy()
    # f on the free dofs, lifted by the Dirichlet values (as the problem's load is)
    load = problem.load_vector().array_r.copy()
    rows = np.repeat(np.arange(c.nodes.size), problem.gdim)
    cols = (c.nodes[:, None] * bs + np.arange(problem.gdim)[None, :]).ravel()
    N = sp.csr_matrix((c.normals.ravel(), (rows, cols)), shape=(c.nodes.size, n))
    finite = np.isfinite(c.gap)
    upper = np.where(finite, c.gap - N @ u_d, np.inf)
    scale = np.sqrt(c.mass)
    C = sp.diags(scale) @ N[:, free]
    return ExtractedQP(
        P=A[free][:, free].tocsc(),
        q=-load[free],
        C=C.tocsc(),
        upper=scale * upper,
        free=free,
        u_d=u_d,
    )


def solve_osqp(problem: ContactProblem, *, tol: float = 1e-10, max_iter: int = 1_000_000):
    """Solve the contact QP with OSQP at a tight tolerance, polished; one process.

    Args:
        problem: A contact problem on ``COMM_SELF`` (any obstacle).
        tol: OSQP's absolute and relative tolerances.
        max_iter: OSQP's iteration cap.

    Returns:
        A :class:`BaselineResult` (λ from the equilibrium residual).

    Raises:
        RuntimeError: If OSQP does not solve the QP.
    """
    import osqp
    import scipy.sparse as sp

    qp = extract_qp(problem)
    solver = osqp.OSQP()
    solver.setup(
        P=sp.triu(qp.P).tocsc(),
        q=qp.q,
        A=qp.C,
        l=np.full(qp.C.shape[0], -np.inf),
        u=qp.upper,
        verbose=False,
        eps_abs=tol,
        eps_rel=tol,
        max_iter=max_iter,
        polishing=True,
    )
    t0 = time.perf_counter()
    res = solver.solve()
    elapsed = time.perf_counter() - t0
    if res.info.status_val not in (1, 2):  # solved, or solved inaccurate
        raise RuntimeError(f"OSQP did not solve the contact QP: {res.info.status}.")
    u = fem.Function(problem.V, name="displacement")
    x = qp.u_d.copy()
    x[qp.free] = res.x
    u.x.petsc_vec.array[:] = x
    u.x.scatter_forward()
    residual = problem.create_vector()
    try:
        problem.A.mult(u.x.petsc_vec, residual)
        residual.aypx(-1.0, problem.load_vector())
        lam = problem.multiplier_from_residual(residual)
    finally:
        residual.destroy()
    return BaselineResult(
        u=u,
        pressure=problem.pressure_function(lam),
        multiplier=lam,
        iterations=int(res.info.iter),
        kkt=compute_kkt_residuals(problem, u.x.petsc_vec, lam),
        time=elapsed,
    )
