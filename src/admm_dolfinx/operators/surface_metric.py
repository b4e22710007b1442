"""The operators of the surface metric R = r (M + β L_Γ) (the 3D default's penalty norm).

ADMM at the paper's penalty r M converges at the rate of the contact pencil
(NᵀMN, A), whose condition number κ grows like 1/h: the compliance of Γ_C falls from
its smoothest to its roughest contact mode. Measuring the splitting residual
p − N u in a norm that *also* grows with roughness,

    ‖q‖²_R = r (qᵀ M q + β qᵀ L_Γ q),    (L_Γ)_ij = ∫_Γc ∇_Γ φ_i · ∇_Γ φ_j ds,

(L_Γ the Laplace–Beltrami stiffness of the contact surface, ∇_Γ the tangential
gradient) compensates that fall, and ADMM's count stops growing under refinement
(``python benchmarks/surface_metric.py --part rule`` measures the pencil's condition
number in both metrics). ADMM with any symmetric positive definite R has the same
fixed points; its steps in this metric are :mod:`admm_dolfinx.admm.surface_projection`'s.

This module holds the operators: L_Γ (a UFL form with the tangential gradient), the
sparse matrix P_N of the contact directions, Nᵀ L_Γ N = P_Nᵀ L_Γ P_N (exact, in
parallel by PETSc: the trace u·n_h of a P1 field is quadratic on a facet, so no UFL
form would be), and L_Γ on the contact nodes, distributed like the contact m-vectors,
for the step-2 QP.
The choice of β and r is :mod:`admm_dolfinx.penalty.surface`'s.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
import ufl
from dolfinx import fem
from dolfinx.fem import petsc as fem_petsc
from mpi4py import MPI
from petsc4py import PETSc
from slepc4py import SLEPc

from admm_dolfinx._mpi import RankLayout, gather_csr
from admm_dolfinx.linalg.petsc import PetscOwner
from admm_dolfinx.problem.contact_problem import ContactProblem

__all__ = ["SurfaceMetric", "surface_gradient"]


def surface_gradient(f: ufl.core.expr.Expr, n: ufl.core.expr.Expr) -> ufl.core.expr.Expr:
    """The tangential gradient ∇f − (∇f · n) n on a facet with unit normal n."""
    grad = ufl.grad(f)
    return grad - ufl.dot(grad, n) * n


class SurfaceMetric(PetscOwner):
    """L_Γ on the contact nodes, Nᵀ L_Γ N on the displacement space, and their layout.

    Args:
        problem: The contact problem (3D).

    Attributes:
        normal_stiffness: Nᵀ L_Γ N in V's layout (Dirichlet rows and columns zero).
        layout: How the contact nodes lie over the ranks (gathered m-vectors: rank order).
    """

    _petsc_objects = ("surface_stiffness", "normal_map", "normal_stiffness", "contact_laplacian")
    # Assembled by the constructor (:meth:`_build`), freed and set to None by
    # :meth:`destroy`, after which the metric is not to be used.
    surface_stiffness: PETSc.Mat
    normal_map: PETSc.Mat
    normal_stiffness: PETSc.Mat
    contact_laplacian: PETSc.Mat

    def __init__(self, problem: ContactProblem):
        self.problem = problem
        self._k_max_squared: float | None = None
        self._work: tuple[PETSc.Vec, PETSc.Vec] | None = None
        self._force: PETSc.Vec | None = None
        try:  # assigns the matrices; a failure frees those already made
            self._build()
        except BaseException:
            self.destroy()  # collective: every rank raised alike
            raise

    def _build(self) -> None:
        """Assemble L_Γ, P_N, Nᵀ L_Γ N and L_Γ on the contact nodes."""
        problem = self.problem
        comm = problem.comm
        c = problem.contact
        Q = c.Q
        msh = Q.mesh
        w, v = ufl.TrialFunction(Q), ufl.TestFunction(Q)
        n = ufl.FacetNormal(msh)
        ds_c = c.measure
        form = fem.form(ufl.inner(surface_gradient(w, n), surface_gradient(v, n)) * ds_c)
        #: L_Γ on the scalar space Q (rows of nodes off Γ_C are zero).
        self.surface_stiffness = fem_petsc.assemble_matrix(form)
        self.surface_stiffness.assemble()

        # P_N: row q_j (the Q dof of contact node j) holds ñ_j at node j's dofs
        q_map, v_map = Q.dofmap.index_map, problem.V.dofmap.index_map
        bs, gdim = problem.V.dofmap.index_map_bs, problem.gdim
        q0, v0 = q_map.local_range[0], v_map.local_range[0]
        P = PETSc.Mat().createAIJ(
            (
                (q_map.size_local, q_map.size_global),
                (v_map.size_local * bs, v_map.size_global * bs),
            ),
            nnz=(gdim, 0),
            comm=comm,
        )
        rows = (q0 + c.dofs).astype(PETSc.IntType)
        for j, row in enumerate(rows):
            cols = ((v0 + c.nodes[j]) * bs + np.arange(gdim)).astype(PETSc.IntType)
            P.setValues([row], cols, c.free_normals[j], addv=PETSc.InsertMode.INSERT_VALUES)
        P.assemble()
        self.normal_map = P
        self.normal_stiffness = self.surface_stiffness.ptap(P)

        # L_Γ restricted to the contact nodes, distributed like the m-vectors: row i on
        # a rank is its i-th owned contact node (the order of c.dofs)
        index_set = PETSc.IS().createGeneral(rows, comm=comm)
        try:
            #: L_Γ on the contact nodes (m × m, the layout of the m-vectors).
            self.contact_laplacian = self.surface_stiffness.createSubMatrix(index_set, index_set)
        finally:
            index_set.destroy()
        #: How the contact nodes lie over the ranks (the order of gathered m-vectors).
        self.layout = RankLayout(comm, c.dofs.size)

    @property
    def k_max_squared(self) -> float:
        """k²_max: the largest eigenvalue of L_Γ x = k² M x (SLEPc); collective.

        Computed on the distributed M^{-½} L_Γ M^{-½}, started from the contact nodes'
        partition-independent probe values, so that it is the same on any partition
        to the eigenvalue tolerance.
        """
        if self._k_max_squared is None:
            self._k_max_squared = self._largest_surface_eigenvalue()
        return self._k_max_squared

    def _largest_surface_eigenvalue(self) -> float:
        c = self.problem.contact
        scaled = self.contact_laplacian.copy()
        scale, start = scaled.createVecs()
        scale.array[:] = 1.0 / np.sqrt(c.mass)
        start.array[:] = c.probe
        scaled.diagonalScale(scale, scale)
        eps = SLEPc.EPS().create(comm=self.problem.comm)
        try:
            eps.setOperators(scaled)
            eps.setProblemType(SLEPc.EPS.ProblemType.HEP)
            eps.setWhichEigenpairs(SLEPc.EPS.Which.LARGEST_REAL)
            eps.setDimensions(nev=1, ncv=min(scaled.getSize()[0], 16))
            eps.setTolerances(tol=1e-4, max_it=1000)
            eps.setInitialSpace([start])
            eps.solve()
            if eps.getConverged() < 1:
                raise RuntimeError(
                    "The largest eigenvalue of the contact surface's Laplacian did not "
                    f"converge (SLEPc reason {eps.getConvergedReason()})."
                )
            return float(eps.getEigenvalue(0).real)
        finally:
            eps.destroy()
            scaled.destroy()
            scale.destroy()
            start.destroy()

    def dense_laplacian(self) -> npt.NDArray[np.float64] | None:
        """L_Γ on the contact nodes in rank order, dense, on rank 0 (None elsewhere).

        For dense checks of the metric (tests, ``benchmarks/surface_metric.py``);
        collective.
        """
        indptr, indices, data = self.contact_laplacian.getValuesCSR()
        gathered = gather_csr(self.problem.comm, (indptr, indices, data))
        if gathered is None:
            return None
        indptr, indices, data = gathered
        m = self.layout.total
        dense = np.zeros((m, m))
        rows = np.repeat(np.arange(m), np.diff(indptr))
        np.add.at(dense, (rows, indices), data)
        return dense

    def penalty_matrix(self, beta: float) -> PETSc.Mat:
        """Nᵀ(M + βL_Γ)N = K + β Nᵀ L_Γ N; collective.

        Its sparsity pattern is that of K and Nᵀ L_Γ N, the couplings of the dofs on
        Γ_C, a subset of A's: not A's whole pattern, which would make every product
        with it (the multigrid's coarse penalties P_lᵀ K P_l) cost as much as with A.

        Args:
            beta: β ≥ 0, the weight of the surface gradient.

        Returns:
            The matrix, in V's layout (the caller destroys it).
        """
        matrix = self.problem.K.copy()
        matrix.axpy(
            beta, self.normal_stiffness, structure=PETSc.Mat.Structure.DIFFERENT_NONZERO_PATTERN
        )
        return matrix

    def add_surface_force(self, b: PETSc.Vec, q: npt.NDArray[np.float64], scale: float) -> None:
        """Add ``scale`` · Nᵀ L_Γ q to ``b`` (q at the owned contact nodes); collective."""
        if self._work is None:
            self._work = self.surface_stiffness.createVecs()
            self._force = self.problem.create_vector()
        q_vec, l_q = self._work
        q_vec.set(0.0)
        q_vec.array[self.problem.contact.dofs] = q
        self.surface_stiffness.mult(q_vec, l_q)
        self.normal_map.multTranspose(l_q, self._force)
        b.axpy(scale, self._force)

    def dirichlet_lift(self, out: PETSc.Vec) -> bool:
        """Set ``out`` = −P_Nᵀ L_Γ d_D, the lifting of β Nᵀ L_Γ N by the Dirichlet values.

        d_D,j = (n_j − ñ_j) · u_D,j is the part of the normal displacement of contact
        node j that Dirichlet conditions prescribe
        (:meth:`~admm_dolfinx.problem.ContactProblem.prescribed_normal_displacement`).
        Collective.

        Returns:
            Whether the lifting is non-zero anywhere (else ``out`` is left untouched).
        """
        problem, c = self.problem, self.problem.contact
        d = problem.prescribed_normal_displacement()
        if not problem.comm.allreduce(bool(np.any(d != 0.0)), op=MPI.LOR):
            return False
        d_q, l_d = self.surface_stiffness.createVecs()
        try:
            d_q.set(0.0)
            d_q.array[c.dofs] = d
            self.surface_stiffness.mult(d_q, l_d)
            self.normal_map.multTranspose(l_d, out)
            out.scale(-1.0)
        finally:
            d_q.destroy()
            l_d.destroy()
        return True

    def destroy(self) -> None:
        """Free the PETSc objects."""
        super().destroy()
        for vec in (*(getattr(self, "_work", None) or ()), getattr(self, "_force", None)):
            if vec is not None:
                vec.destroy()
        self._work = self._force = None
