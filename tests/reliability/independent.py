"""An independent check of a contact solution, from the user's UFL forms.

It does not use the problem's matrices or the package's KKT module: the equilibrium
residual is assembled anew from ``a`` and ``L`` (the residual form a(u, ·) − L), the
contact force is built node by node from λ, the normals and the lumped mass, and the
gap is asked of the obstacle again.
"""

from __future__ import annotations

import numpy as np
import ufl
from dolfinx import fem
from dolfinx.fem import petsc as fem_petsc
from mpi4py import MPI
from petsc4py import PETSc


def residuals(problem, a, L, result) -> dict[str, float]:
    """Relative equilibrium, penetration and complementarity of ``result``."""
    comm = problem.comm
    V = problem.V
    bs = V.dofmap.index_map_bs
    u = result.u
    form = fem.form(ufl.action(a, u) - L)
    vec = fem_petsc.assemble_vector(form)
    vec.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
    load = fem_petsc.assemble_vector(fem.form(L))
    load.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
    c = problem.contact
    lam = np.asarray(result.multiplier)
    n_owned = V.dofmap.index_map.size_local * bs
    fixed = np.zeros(n_owned, dtype=bool)
    for bc in problem.bcs:
        dofs = bc.dof_indices()[0]
        fixed[dofs[dofs < n_owned]] = True
    force = np.zeros((n_owned // bs, bs))
    force[c.nodes, : problem.gdim] = (c.mass * lam)[:, None] * c.normals
    force = force.reshape(-1)
    r = vec.array_r.copy() + force
    f = load.array_r.copy()
    au = vec.array_r + f  # a(u, ·)
    for x in (r, f, au, force):
        x[fixed] = 0.0
    vec.destroy()
    load.destroy()

    def norm(x):
        return float(np.sqrt(comm.allreduce(float(x @ x), op=MPI.SUM)))

    def norm_inf(x):
        return float(comm.allreduce(float(np.max(np.abs(x), initial=0.0)), op=MPI.MAX))

    values = u.x.array.reshape(-1, bs)[c.nodes, : problem.gdim]
    nu = np.einsum("ij,ij->i", values, c.normals)
    gap = np.asarray(problem.obstacle.gap(c.coordinates.copy(), c.normals.copy()), dtype=float)
    slack = np.where(np.isfinite(gap), gap - nu, np.inf)
    u_scale = norm_inf(u.x.array[:n_owned]) or 1.0
    lam_scale = norm_inf(lam) or 1.0
    return {
        "equilibrium": norm(r) / max(norm(au), norm(f), norm(force), 1e-300),
        "penetration": norm_inf(np.maximum(-slack, 0.0)) / u_scale,
        "complementarity": norm_inf(np.where(lam != 0, lam * np.abs(slack), 0.0))
        / (lam_scale * u_scale),
        "adhesion": norm_inf(np.maximum(-lam, 0.0)) / lam_scale,
    }


def assert_honest(problem, a, L, solve, rtol: float) -> object:
    """Either a clear error (ADMMConvergenceError or ValueError) or a verified answer.

    Returns:
        The result if it claimed convergence (verified), else the exception.
    """
    from admm_dolfinx import ADMMConvergenceError

    try:
        result = solve()
    except (ADMMConvergenceError, ValueError, RuntimeError) as error:
        if isinstance(error, ADMMConvergenceError):
            assert error.result.converged is False
            assert error.result.status in ("max_iter", "inaccurate", "inexact_step1")
        return error
    if result.converged:
        check = residuals(problem, a, L, result)
        assert max(check.values()) <= 2 * rtol, check
    else:
        assert result.status == "callback"
    return result
