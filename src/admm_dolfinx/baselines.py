"""Reference solvers for the same discrete contact problem (for tests and benchmarks).

:func:`solve_snes_vi` solves the QP of :class:`~admm_dolfinx.ContactProblem` as a
variational inequality with PETSc's semismooth active-set Newton method
(``vinewtonrsls``) and a MUMPS factorisation of the reduced Jacobian. It is exact up
to round-off once the active set is identified, and entirely independent of the ADMM
code path. PETSc's VI solvers take *bounds* on the unknowns, so it applies where the
nodal normals of all contact nodes are axis-aligned (flat contact parallel to a
coordinate plane); it raises otherwise.
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

from admm_dolfinx.kkt import KKTResiduals, compute_kkt_residuals
from admm_dolfinx.petsc import prefixed_options, unique_prefix
from admm_dolfinx.problem import ContactProblem

__all__ = ["BaselineResult", "solve_snes_vi"]

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
