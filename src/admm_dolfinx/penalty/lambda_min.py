"""λ_min, the small end of the contact pencil's spectrum (Koko 2019, §5), for r*.

λ_min = 1 / μ_max, μ_max the largest eigenvalue of M^{-½} S M^{-½}, S the Schur
complement of A onto the contact normal dofs. The large end of that operator converges
in tens of applications (the small end of the wrong operator would take hundreds).

S x is the reaction of the body when its contact normal displacements are prescribed
to x: u = N_Fᵀ D⁻¹ x + w with w in ker N_F minimising the energy, found with one solve
with Â = P A P + c N_FᵀN_F (:func:`~admm_dolfinx.linalg.contact_space.projected_stiffness`;
Â is A_II in rotated coordinates, plus c on the normal dofs). Then S x = D⁻¹ N_F A u.
Â is well posed even when A is singular (floating bodies), because every rigid motion
of such a body moves Γ_C normally.

The eigenvector of μ_max is the shortest-wave contact mode, which lives within a few
elements of Γ_C. So the ``"local"`` method needs no factorisation of the whole body:
S is replaced by the Schur complement S_L of a layer of L rings of cells along Γ_C,
with the rest held fixed (S_L ≥ S, and S_L = S once the layer is the whole mesh);
L = 1, 2, 4, ... until μ_max settles to the tolerance the caller needs, each layer
costing a factorisation of its own Â (:func:`lambda_min_from_layers`). On a mesh graded
towards Γ_C a layer of many rings holds much of the body, so the layers stop as soon
as they can: the truncation error falls by more than half per doubling of L, so the
last change bounds the error left in the last layer's value. The
``"factorised"`` method uses the exact S, with one factorisation of the whole Â in the
solver's shared operator (:func:`lambda_min_exact`).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from petsc4py import PETSc

from admm_dolfinx.linalg.contact_space import ContactSpace, NodalMap, projected_stiffness
from admm_dolfinx.linalg.petsc import (
    check_solve,
    create_factor_solver,
    prepare_eigensolve,
    top_eigenpair,
)
from admm_dolfinx.problem.contact_layer import contact_layer, layer_index_set

__all__ = [
    "SchurOperator",
    "lambda_min_exact",
    "lambda_min_from_layers",
]


class SchurOperator:
    """x ↦ M^{-½} S M^{-½} x with S the Schur complement onto contact normal dofs.

    Works on the whole mesh (exact S) or on a layer of elements along Γ_C with the
    rest held fixed (S_L ≥ S, converging to S as the layer grows).

    Args:
        space: The contact space (m-vectors, masses).
        A: The stiffness the Schur complement is taken of (whole or layer).
        nodal: Contact node positions in A's local node numbering.
        solver: Has ``solve(b, x)`` with a factorisation of ``projected_stiffness``.
    """

    def __init__(self, space: ContactSpace, A: PETSc.Mat, nodal: NodalMap, solver):
        self.space = space
        self.A = A
        self.nodal = nodal
        self.solver = solver
        self.u, self.rhs = A.createVecs()
        self.w, self.work = A.createVecs()

    def mult(self, mat, x, y):
        """Apply y = M^{-½} S M^{-½} x (one solve with the projected stiffness)."""
        s, nodal = self.space, self.nodal
        # u = N_Fᵀ D⁻¹ z (z = M^{-½} x): a displacement with the prescribed normal trace
        z = x.array_r / s.sqrt_mass
        nodal.scatter(z, self.u, 1.0 / s.free_sq)
        # w ∈ ker N_F minimising the energy: Â w = −P A u  (P A u = A u − N_Fᵀ D⁻¹ N_F A u)
        self.A.mult(self.u, self.work)
        nodal.scatter(nodal.gather(self.work), self.rhs, 1.0 / s.free_sq)
        self.rhs.aypx(-1.0, self.work)  # rhs = P A u
        self.rhs.scale(-1.0)
        self.solver.solve(self.rhs, self.w)
        self.u.axpy(1.0, self.w)  # u + w
        self.A.mult(self.u, self.work)
        with y as out:
            out[:] = nodal.gather(self.work) / s.free_sq / s.sqrt_mass

    def free(self):
        """Free the work vectors."""
        for obj in (self.u, self.rhs, self.w, self.work):
            obj.destroy()


class _LayerSolver:
    """A factorised small matrix (the projected stiffness of a layer along Γ_C)."""

    def __init__(self, matrix: PETSc.Mat, prefix: str, options: dict | None):
        # factorises
        self.ksp = create_factor_solver(matrix, prefix, options, what="a layer of the r* estimate")
        self.solves = 0

    def solve(self, b, x):
        """Solve with the factorisation; raise if it failed."""
        self.ksp.solve(b, x)
        self.solves += 1
        check_solve(self.ksp, "the projected stiffness of a layer along Γ_C")

    def destroy(self):
        """Free the KSP."""
        self.ksp.destroy()


def _top_of_schur(space, schur, prefix, tol, max_it, start) -> tuple[float, PETSc.Vec, int]:
    """μ_max, its eigenvector (caller destroys it) and the restarts; collective."""
    mat = space.shell(schur)
    eps = space.krylov_schur(mat, tol, max_it)
    try:
        prepare_eigensolve(eps, prefix=prefix, start=[start])
        eps.solve()
        return top_eigenpair(
            eps,
            f"SLEPc did not converge to the largest eigenvalue of the contact Schur "
            f"complement within {max_it} restarts (tol {tol:g}). Loosen penalty_tol or "
            "give the penalty explicitly",
        )
    finally:
        eps.destroy()
        mat.destroy()


def lambda_min_from_layers(
    space: ContactSpace,
    tol: float,
    max_it: int,
    prefix: str,
    options,
    start: PETSc.Vec,
    layer_tol: float | None,
    rings: int | None = None,
) -> tuple[float, dict[str, Any]]:
    """λ_min from μ_max of the Schur complement of growing layers along Γ_C; collective.

    S_L (the rest of the body held fixed beyond L rings of cells) is stiffer than S
    and tends to it as L grows: μ_max(S_L) decreases to μ_max(S). L = 1, 2, 4, ...
    until two successive μ_max agree to ``layer_tol`` or the layer is the whole mesh
    (then S_L = S exactly). The value of the wider layer is returned; its truncation
    error is below the last change as long as the error at least halves per doubling
    of L (``tests/penalty/test_estimate.py`` checks λ_min against the dense pencil).
    With ``rings`` instead, the layer of that many rings alone: a lower bound of
    λ_min (S_L ≥ S) with no growth check, for a caller that needs λ_min roughly;
    ``rings=0`` is the contact nodes alone (every other node held fixed: S_0 is the
    Schur complement of A's block on the contact nodes, a surface problem).

    Args:
        space: The contact space.
        tol: Eigenvalue tolerance of each layer's eigenvalue solve.
        max_it: Krylov–Schur restarts.
        prefix: Options prefix; the layer factorisations read ``{prefix}layer_``, the
            eigensolver ``{prefix}lmin_``.
        options: Options of the layer factorisations (MUMPS Cholesky by default).
        start: Start vector of the first layer (each wider layer starts from the
            previous eigenvector).
        layer_tol: Relative agreement of two successive layers that ends the growth
            (``None`` with ``rings``).
        rings: Rings of the one layer to use (≥ 0), without growth (``None``: grow).

    Returns:
        λ_min and details (``layers``, ``layer_steps``, ``solves_min``, ``restarts_min``).
    """
    if (layer_tol is None) == (rings is None):
        raise ValueError("give one of layer_tol (grow the layers) and rings (one layer).")
    if rings is not None and rings < 0:
        raise ValueError(f"rings must be ≥ 0, got {rings}.")
    problem = space.problem
    bs = space.map.bs
    previous, layers, solves, steps = None, 1 if rings is None else rings, 0, 0
    vec = None
    try:
        while True:
            steps += 1
            nodes, whole = contact_layer(problem, layers)
            nodal = NodalMap(
                np.searchsorted(nodes, problem.contact.nodes),
                problem.contact.free_normals,
                bs,
                space.gdim,
            )
            index_set = A_layer = hat = solver = schur = None
            try:
                index_set = layer_index_set(problem, nodes)
                A_layer = problem.A.createSubMatrix(index_set, index_set)
                hat = projected_stiffness(A_layer, nodal)
                solver = _LayerSolver(hat, prefix + "layer_", options)
                schur = SchurOperator(space, A_layer, nodal, solver)
                mu, new, its = _top_of_schur(
                    space, schur, prefix + "lmin_", tol, max_it, start if vec is None else vec
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
            if vec is not None:
                vec.destroy()
            vec = new  # warm start the next, wider layer
            agree = (
                previous is not None
                and layer_tol is not None
                and abs(previous - mu) <= layer_tol * mu
            )
            if whole or rings is not None or agree:
                details = {
                    "layers": "all" if whole else layers,
                    "layer_steps": steps,
                    "solves_min": solves,
                    "restarts_min": its,
                }
                return 1.0 / mu, details
            previous, layers = mu, 2 * layers
    finally:
        if vec is not None:
            vec.destroy()


def lambda_min_exact(
    space: ContactSpace, operator, tol: float, max_it: int, prefix: str, start: PETSc.Vec
) -> tuple[float, dict[str, Any]]:
    """λ_min from μ_max of the exact Schur complement S; collective.

    Args:
        space: The contact space.
        operator: A :class:`~admm_dolfinx.operators.penalised.PenalisedOperator`; the
            projected stiffness of the whole body is factorised in it (numerically:
            its symbolic analysis is shared with the ADMM's step 1).
        tol: Eigenvalue tolerance.
        max_it: Krylov–Schur restarts.
        prefix: Options prefix; the eigensolver reads ``{prefix}lmin_``.
        start: Start vector.

    Returns:
        λ_min and details (``layers="all"``, ``solves_min``, ``restarts_min``).
    """
    problem = space.problem
    solves_before = operator.solves
    hat = projected_stiffness(problem.A, space.map)
    operator.load(hat, "the projected stiffness P A P + c NᵀN (Schur complement)")
    hat.destroy()
    schur = SchurOperator(space, problem.A, space.map, operator)
    vec = None
    try:
        mu, vec, its = _top_of_schur(space, schur, prefix + "lmin_", tol, max_it, start)
    finally:
        schur.free()
        if vec is not None:
            vec.destroy()
    details = {
        "layers": "all",
        "layer_steps": 0,
        "solves_min": operator.solves - solves_before,
        "restarts_min": its,
    }
    return 1.0 / mu, details
