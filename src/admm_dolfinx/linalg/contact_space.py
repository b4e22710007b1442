"""The contact normal space: m-vectors on the contact nodes, and N between it and V.

The m × m operators of the penalty estimate (:mod:`admm_dolfinx.penalty`) act on
distributed m-vectors, one value per owned contact node. This module holds what they
share:

* :class:`NodalMap`: N_F and N_Fᵀ between contact-node values and vectors of a
  (sub)space with bs dofs per node (the whole V, or a layer of cells along Γ_C);
* :class:`ContactSpace`: the distributed m-vectors, work vectors of V, and the PETSc
  Python shell that applies an m × m operator;
* :func:`projected_stiffness`: Â = P A P + c N_FᵀN_F, whose solves give the Schur
  complement of A onto the contact normal dofs (and the polishing's reduced solves).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt
from dolfinx.fem import petsc as fem_petsc
from petsc4py import PETSc
from slepc4py import SLEPc

from admm_dolfinx.linalg.petsc import mean_diagonal

__all__ = ["ContactSpace", "NodalMap", "ProjectedStiffness", "projected_stiffness"]


class NodalMap:
    """Contact-node values to and from vectors of a (sub)space with bs dofs per node.

    Args:
        nodes: The contact nodes' positions in the (sub)space's local node numbering.
        free_normals: Their normals ñ_j with Dirichlet-fixed components zeroed.
        bs: Dofs per node.
        gdim: Geometric dimension (the first gdim dofs of a node are its displacement).
    """

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
    """Distributed m-vectors on the owned contact nodes, and the operators' plumbing.

    Args:
        problem: The contact problem (a
            :class:`~admm_dolfinx.problem.contact_problem.ContactProblem`).

    Attributes:
        m_local: Owned contact nodes; m: all of them.
        gdim: Geometric dimension.
        sqrt_mass: M^{½} on the owned contact nodes.
        free_sq: D_jj = |ñ_j|².
        map: N_F on the whole displacement space.
        b, x: Work vectors of V.
    """

    def __init__(self, problem: Any):
        self.problem = problem
        c = problem.contact
        self.comm = problem.comm
        self.m_local = c.dofs.size
        self.m = c.num_global
        self.gdim = problem.mesh.geometry.dim
        self.sqrt_mass = np.sqrt(c.mass)
        self.free_sq = np.einsum("ij,ij->i", c.free_normals, c.free_normals)  # D = |ñ|²
        self.map = NodalMap(c.nodes, c.free_normals, problem.V.dofmap.index_map_bs, self.gdim)
        self.b = self.create_full_vector()
        self.x = self.create_full_vector()

    def create_full_vector(self) -> PETSc.Vec:
        """A vector in the layout of V (caller destroys it)."""
        return fem_petsc.create_vector(self.problem.V)

    def create_vec(self) -> PETSc.Vec:
        """A distributed m-vector (owned contact nodes; caller destroys it)."""
        return PETSc.Vec().createMPI((self.m_local, self.m), comm=self.comm)

    def start_vector(self) -> PETSc.Vec:
        """A partition-independent pseudo-random m-vector (from node coordinates)."""
        vec = self.create_vec()
        with vec as arr:
            arr[:] = self.problem.contact.probe
        return vec

    def shell(self, context: Any) -> PETSc.Mat:
        """An m × m PETSc Python matrix applying ``context.mult`` (caller destroys it)."""
        size = (self.m_local, self.m)
        mat = PETSc.Mat().createPython((size, size), context, comm=self.comm)
        mat.setUp()
        return mat

    def krylov_schur(self, mat: PETSc.Mat, tol: float, max_it: int) -> SLEPc.EPS:
        """A Krylov–Schur eigensolver for the largest eigenvalue of a symmetric m × m shell.

        The caller gives it its start (:func:`~admm_dolfinx.linalg.petsc.prepare_eigensolve`),
        runs ``solve()`` and destroys it.
        """
        eps = SLEPc.EPS().create(comm=self.comm)
        eps.setOperators(mat)
        eps.setProblemType(SLEPc.EPS.ProblemType.HEP)
        eps.setType(SLEPc.EPS.Type.KRYLOVSCHUR)
        eps.setWhichEigenpairs(SLEPc.EPS.Which.LARGEST_REAL)
        # A small basis restarts (and checks convergence) early: cheapest at loose tol.
        eps.setDimensions(nev=1, ncv=min(self.m, 8 if tol >= 1e-4 else 32))
        eps.setTolerances(tol=tol, max_it=max_it)
        return eps

    def destroy(self) -> None:
        """Free the work vectors."""
        self.b.destroy()
        self.x.destroy()


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
    former = ProjectedStiffness(A)
    try:
        hat = former.form(nodal)
        former._hat = None  # the caller's now
        return hat
    finally:
        former.destroy()


class ProjectedStiffness:
    """Â (:func:`projected_stiffness`) of one A for guess after guess; collective.

    P holds a full bs × bs block at every node, whatever the guess, so every Â of A has
    one sparsity pattern: P's values are overwritten in place and the triple product
    PᵀAP repeats only its numeric phase.

    Args:
        A: Stiffness (global, or a sub-matrix of whole nodes) with bs dofs per node.
    """

    def __init__(self, A: PETSc.Mat):
        self.A = A
        self._projector: PETSc.Mat | None = None
        self._hat: PETSc.Mat | None = None
        self._c = mean_diagonal(A)

    def form(self, nodal: NodalMap) -> PETSc.Mat:
        """Â of the nodes of ``nodal``: this object's matrix, valid until the next call."""
        A = self.A
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
        if self._projector is None:
            self._projector = PETSc.Mat().createAIJ(
                sizes, csr=(indptr, indices, p_blocks.reshape(-1)), comm=comm
            )
            self._hat = A.PtAP(self._projector)
        else:
            assert self._hat is not None
            # the same pattern: new values in place, the product's numeric phase only
            self._projector.setValuesCSR(indptr, indices, p_blocks.reshape(-1))
            self._projector.assemble()
            A.PtAP(self._projector, result=self._hat)
        Q = PETSc.Mat().createAIJ(sizes, csr=(indptr, indices, q_blocks.reshape(-1)), comm=comm)
        try:
            self._hat.axpy(self._c, Q, structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN)
        finally:
            Q.destroy()
        self._hat.setOption(PETSc.Mat.Option.SPD, True)
        return self._hat

    def destroy(self) -> None:
        """Free P and Â; collective."""
        for obj in (self._projector, self._hat):
            if obj is not None:
                obj.destroy()
        self._projector = self._hat = None
