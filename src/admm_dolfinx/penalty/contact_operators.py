"""Operators on the contact normal dofs for the r* estimate: the m × m pencil (M, S).

Distributed m-vectors live on the owned contact nodes. The operators are applied as
PETSc Python shells and their largest eigenvalue computed with SLEPc Krylov–Schur:

* :class:`SchurOperator`: x ↦ M^{-½} S M^{-½} x, S the Schur complement onto the contact
  normal dofs (of the whole body, or of a layer of cells along Γ_C, see
  :func:`contact_layer`), applied with one solve with :func:`projected_stiffness`;
* :class:`ComplianceOperator`: x ↦ M^{½} N (A + r_a NᵀMN)⁻¹ Nᵀ M^{½} x.

Used by :mod:`admm_dolfinx.penalty.estimate`, which explains the mathematics.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt
from dolfinx import fem, la
from mpi4py import MPI
from petsc4py import PETSc
from slepc4py import SLEPc

from admm_dolfinx._mpi import probe_vector
from admm_dolfinx.linalg.operators import PenalisedOperator
from admm_dolfinx.linalg.petsc import (
    check_solve,
    create_factor_solver,
    solve_top_eigenpair,
)
from admm_dolfinx.problem.contact_problem import ContactProblem

__all__ = [
    "ComplianceOperator",
    "ContactSpace",
    "LocalSolver",
    "NodalMap",
    "SchurOperator",
    "contact_layer",
    "largest_eigenvalue",
    "mean_diagonal",
    "projected_stiffness",
]


class NodalMap:
    """Contact-node values to and from vectors of a (sub)space with bs dofs per node."""

    def __init__(self, nodes, free_normals, bs: int, gdim: int):
        self.nodes = np.asarray(nodes)
        self.free_normals = free_normals
        self.bs = bs
        self.gdim = gdim

    def scatter(self, q, out: PETSc.Vec, weights) -> None:
        """Out = Σ_j ñ_j weights_j q_j  (a nodal force; Dirichlet components zero)."""
        out.set(0.0)
        with out as arr:
            arr.reshape(-1, self.bs)[self.nodes, : self.gdim] = (
                self.free_normals * (weights * q)[:, None]
            )

    def gather(self, vec: PETSc.Vec) -> npt.NDArray[np.float64]:
        """(N_F v)_j = ñ_j · v_j at the owned contact nodes."""
        values = vec.array_r.reshape(-1, self.bs)[self.nodes, : self.gdim]
        return np.einsum("ij,ij->i", values, self.free_normals)


class ContactSpace:
    """Distributed m-vectors on the owned contact nodes, and the operators' plumbing."""

    def __init__(self, problem: ContactProblem):
        self.problem = problem
        c = problem.contact
        self.m_local = c.dofs.size
        self.m = c.num_global
        self.sqrt_mass = np.sqrt(c.mass)
        self.free_sq = np.einsum("ij,ij->i", c.free_normals, c.free_normals)  # D = |ñ|²
        self.map = NodalMap(c.nodes, c.free_normals, problem.V.dofmap.index_map_bs, problem.gdim)
        self.b = problem.create_vector()
        self.x = problem.create_vector()

    def create_vec(self) -> PETSc.Vec:
        """A distributed m-vector (owned contact nodes)."""
        vec = PETSc.Vec().createMPI((self.m_local, self.m), comm=self.problem.comm)
        return vec

    def start_vector(self) -> PETSc.Vec:
        """A partition-independent pseudo-random m-vector (from node coordinates)."""
        vec = self.create_vec()
        with vec as arr:
            arr[:] = probe_vector(self.problem.contact.coordinates)
        return vec

    def shell(self, context: Any) -> PETSc.Mat:
        """An m × m PETSc Python matrix applying ``context.mult``."""
        size = (self.m_local, self.m)
        mat = PETSc.Mat().createPython((size, size), context, comm=self.problem.comm)
        mat.setUp()
        return mat

    def destroy(self) -> None:
        """Free the work vectors."""
        self.b.destroy()
        self.x.destroy()


class ComplianceOperator:
    """x ↦ M^{½} N (A + r_a K)⁻¹ Nᵀ M^{½} x  (eigenvalues θ = λ/(1 + r_a λ))."""

    def __init__(self, space: ContactSpace, operator: PenalisedOperator):
        self.space = space
        self.operator = operator

    def mult(self, mat, x, y):
        """Apply y = M^{½} N (A + r_a K)⁻¹ Nᵀ M^{½} x (one substitution)."""
        s = self.space
        s.map.scatter(x.array_r, s.b, s.sqrt_mass)
        self.operator.solve(s.b, s.x)
        with y as out:
            out[:] = s.sqrt_mass * s.map.gather(s.x)


def projected_stiffness(A: PETSc.Mat, nodal: NodalMap) -> PETSc.Mat:
    """Â = P A P + c N_FᵀN_F with the nodal projector P = I − N_Fᵀ D⁻¹ N_F.

    In coordinates rotated to each contact node's normal, Â is A with the normal rows
    and columns replaced by c times the identity: a solve with Â is a solve with A_II.

    Args:
        A: Stiffness (global, or a sub-matrix of whole nodes) with bs dofs per node.
        nodal: The contact nodes' positions in A's local node numbering.

    Returns:
        Â (the caller destroys it).
    """
    bs = nodal.bs
    n_nodes = A.getLocalSize()[0] // bs
    row0 = A.getOwnershipRange()[0]
    ntilde = np.zeros((nodal.nodes.size, bs))
    ntilde[:, : nodal.gdim] = nodal.free_normals
    outer = np.einsum("ji,jk->jik", ntilde, ntilde)
    p_blocks = np.tile(np.eye(bs), (n_nodes, 1, 1))
    p_blocks[nodal.nodes] -= outer / np.einsum("ji,ji->j", ntilde, ntilde)[:, None, None]
    q_blocks = np.zeros_like(p_blocks)
    q_blocks[nodal.nodes] = outer
    cols = row0 + (np.arange(n_nodes)[:, None] * bs + np.arange(bs)[None, :])
    indices = np.repeat(cols, bs, axis=0).reshape(-1).astype(PETSc.IntType)
    indptr = np.arange(0, n_nodes * bs * bs + 1, bs, dtype=PETSc.IntType)
    sizes = A.getSizes()
    comm = A.getComm()
    P = PETSc.Mat().createAIJ(sizes, csr=(indptr, indices, p_blocks.reshape(-1)), comm=comm)
    Q = PETSc.Mat().createAIJ(sizes, csr=(indptr, indices, q_blocks.reshape(-1)), comm=comm)
    c_scale = mean_diagonal(A)
    hat = A.PtAP(P)
    hat.axpy(c_scale, Q, structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN)
    hat.setOption(PETSc.Mat.Option.SPD, True)
    P.destroy()
    Q.destroy()
    return hat


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


class LocalSolver:
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


def contact_layer(problem: ContactProblem, layers: int) -> tuple[np.ndarray, bool]:
    """Owned nodes within ``layers`` rings of cells of the contact nodes; collective.

    Args:
        problem: The contact problem.
        layers: Number of rings of cells around the contact nodes.

    Returns:
        The sorted local node indices, and whether the layer is the whole mesh.
    """
    Q = problem.contact.Q
    marker = fem.Function(Q)
    marker.x.array[:] = 0.0
    marker.x.array[problem.contact.dofs] = 1.0
    marker.x.scatter_forward()
    cell_dofs = Q.dofmap.list
    for _ in range(layers):
        touched = marker.x.array[cell_dofs].max(axis=1) > 0.0
        grown = np.zeros_like(marker.x.array)
        grown[cell_dofs[touched].ravel()] = 1.0
        marker.x.array[:] = grown
        marker.x.scatter_reverse(la.InsertMode.add)
        marker.x.array[:] = np.minimum(marker.x.array, 1.0)
        marker.x.scatter_forward()
    n_owned = Q.dofmap.index_map.size_local
    owned = np.flatnonzero(marker.x.array[:n_owned] > 0.0)
    total = problem.comm.allreduce(owned.size, op=MPI.SUM)
    nodes = np.sort(problem.contact.q_to_node[owned])
    return nodes.astype(np.int32), total == Q.dofmap.index_map.size_global


def largest_eigenvalue(
    space: ContactSpace,
    context: Any,
    prefix: str,
    tol: float,
    max_it: int,
    deflation: list[PETSc.Vec],
    start: PETSc.Vec,
) -> tuple[float, PETSc.Vec, int]:
    """Largest eigenvalue (and vector) of a symmetric shell operator; collective."""
    mat = space.shell(context)
    eps = SLEPc.EPS().create(comm=space.problem.comm)
    try:
        eps.setOperators(mat)
        eps.setProblemType(SLEPc.EPS.ProblemType.HEP)
        eps.setType(SLEPc.EPS.Type.KRYLOVSCHUR)
        eps.setWhichEigenpairs(SLEPc.EPS.Which.LARGEST_REAL)
        # A small basis restarts (and checks convergence) early: cheapest at loose tol.
        eps.setDimensions(nev=1, ncv=min(space.m, 8 if tol >= 1e-4 else 32))
        eps.setTolerances(tol=tol, max_it=max_it)
        value, vec, its = solve_top_eigenpair(
            eps,
            space.create_vec,
            f"SLEPc did not converge to the extreme eigenvalue of the contact pencil "
            f"within {max_it} restarts (tol {tol:g}). Loosen penalty_tol or give the "
            "penalty explicitly",
            prefix=prefix,
            start=[start],
            deflation=deflation,
        )
        return value, vec, its
    finally:
        eps.destroy()
        mat.destroy()


def mean_diagonal(matrix: PETSc.Mat) -> float:
    """Mean of the diagonal (a scale of the matrix); collective."""
    diagonal = matrix.getDiagonal()
    value = diagonal.sum() / diagonal.getSize()
    diagonal.destroy()
    return value
