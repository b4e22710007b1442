"""The surface metric of the penalty: R = r (M + β L_Γ) instead of r M (3D default).

ADMM at the paper's penalty r M converges at the rate of the contact pencil
(NᵀMN, A), whose condition number κ grows like 1/h: the compliance of Γ_C falls from
its smoothest to its roughest contact mode. Measuring the splitting residual
p − N u in a norm that *also* grows with roughness,

    ‖q‖²_R = r (qᵀ M q + β qᵀ L_Γ q),    (L_Γ)_ij = ∫_Γc ∇_Γ φ_i · ∇_Γ φ_j ds,

(L_Γ the Laplace–Beltrami stiffness of the contact surface, ∇_Γ the tangential
gradient) compensates that fall: the pencil (Nᵀ(M + βL_Γ)N, A) has a condition
number of 2.3–6.3 on every mesh of ``python benchmarks/surface_metric.py --part
rule``, where the paper's has 4.7–84 and grows like 1/h, and ADMM's count stops
growing under refinement. ADMM with any symmetric positive definite R has the same
fixed points (p = N u, λ the contact pressure); only two steps change:

    (A + NᵀR N) u = f + Nᵀ (R p − M λ)                      step 1 (stored factors)
    p⁺ = argmin_{p ≤ g} ½ (p − q)ᵀ R (p − q),  R q = R ξ + M λ   step 2: a QP on Γ_C
    λ⁺ = M⁻¹ R (q − p⁺)                                     step 3: its multiplier

Step 2 is no longer node-wise; it is a bound-constrained QP on the contact surface
(m unknowns, a sparse surface matrix), solved exactly on rank 0 by a primal-dual
active-set method warm-started from the previous iteration's contact set (one sparse
Cholesky factorisation per change of the set). λ⁺ ≥ 0 and λ⁺(g − p⁺) = 0 hold by
construction. With β = 0 it is the paper's step 2 and 3 exactly.

Nᵀ L_Γ N is not a UFL form (the trace u·n_h of a P1 field is quadratic on a facet);
it is assembled exactly as P_Nᵀ L_Γ P_N with P_N the sparse matrix of the nodal
normals (:meth:`SurfaceMetric.__init__`), in parallel by PETSc.

The choice of β and r is :mod:`admm_dolfinx.surface_penalty`'s.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
import ufl
from dolfinx import fem
from dolfinx.fem import petsc as fem_petsc
from mpi4py import MPI
from petsc4py import PETSc
from slepc4py import SLEPc

from admm_dolfinx._mpi import RankLayout, gather_csr, run_on_rank0
from admm_dolfinx.contact import contact_measure
from admm_dolfinx.petsc import PetscOwner
from admm_dolfinx.problem import ContactProblem

__all__ = ["SurfaceMetric", "SurfaceProjection", "surface_gradient"]

#: Rounds of the active-set method per projection before it gives up. With a warm
#: start it needs 1–3; it is finite for M-matrices and in practice for any mesh.
MAX_ACTIVE_SET_ROUNDS = 100


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

    _petsc_objects = ("surface_stiffness", "normal_map", "normal_stiffness")

    def __init__(self, problem: ContactProblem):
        self.problem = problem
        self.surface_stiffness = self.normal_map = self.normal_stiffness = None
        self._rank0: dict | None = None
        self._k_max_squared: float | None = None
        self._work: tuple[PETSc.Vec, PETSc.Vec] | None = None
        self._force: PETSc.Vec | None = None
        try:
            self._build()
        except BaseException:
            self.destroy()  # collective: every rank raised alike
            raise

    def _build(self) -> None:
        """Assemble L_Γ, P_N and Nᵀ L_Γ N; gather L_Γ on the contact nodes to rank 0."""
        problem = self.problem
        comm = problem.comm
        c = problem.contact
        Q = c.Q
        msh = Q.mesh
        w, v = ufl.TrialFunction(Q), ufl.TestFunction(Q)
        n = ufl.FacetNormal(msh)
        ds_c = contact_measure(msh, problem.facet_tags, problem.contact_marker)
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

        # L_Γ restricted to the contact nodes, gathered on rank 0 in rank order
        index_set = PETSc.IS().createGeneral(rows, comm=comm)
        sub = self.surface_stiffness.createSubMatrix(index_set, index_set)
        csr = sub.getValuesCSR()
        sub.destroy()
        index_set.destroy()
        #: How the contact nodes lie over the ranks (the order of gathered m-vectors).
        self.layout = RankLayout(comm, c.dofs.size)
        gathered = gather_csr(comm, csr)
        masses = self.layout.gather(c.mass)

        def build() -> dict:
            indptr, indices, data = gathered
            m = self.layout.total
            laplacian = PETSc.Mat().createAIJ(
                (m, m),
                csr=(indptr.astype(PETSc.IntType), indices.astype(PETSc.IntType), data),
                comm=PETSc.COMM_SELF,
            )
            return {"laplacian": laplacian, "mass": masses}

        def failure(name: str, text: str, _: bool) -> Exception:
            return RuntimeError(f"Gathering L_Γ on rank 0 failed: {name}: {text}")

        #: L_Γ and M on the contact nodes, on rank 0 (None elsewhere).
        self._rank0 = run_on_rank0(comm, build, failure, broadcast=False)

    @property
    def k_max_squared(self) -> float:
        """k²_max: the largest eigenvalue of L_Γ x = k² M x (SLEPc, rank 0); collective."""
        if self._k_max_squared is None:
            self._k_max_squared = run_on_rank0(
                self.problem.comm,
                self._largest_surface_eigenvalue,
                lambda name, text, _: RuntimeError(
                    f"The largest eigenvalue of the contact surface's Laplacian failed: "
                    f"{name}: {text}"
                ),
            )
        return self._k_max_squared

    def _largest_surface_eigenvalue(self) -> float:
        laplacian, mass = self._rank0["laplacian"], self._rank0["mass"]
        scaled = laplacian.copy()
        scale = scaled.createVecLeft()
        scale.array[:] = 1.0 / np.sqrt(mass)
        scaled.diagonalScale(scale, scale)
        eps = SLEPc.EPS().create(comm=PETSc.COMM_SELF)
        try:
            eps.setOperators(scaled)
            eps.setProblemType(SLEPc.EPS.ProblemType.HEP)
            eps.setWhichEigenpairs(SLEPc.EPS.Which.LARGEST_REAL)
            eps.setDimensions(nev=1, ncv=min(scaled.getSize()[0], 16))
            eps.setTolerances(tol=1e-4, max_it=1000)
            eps.solve()
            if eps.getConverged() < 1:
                raise RuntimeError(f"SLEPc reason {eps.getConvergedReason()}")
            return float(eps.getEigenvalue(0).real)
        finally:
            eps.destroy()
            scaled.destroy()
            scale.destroy()

    def dense_laplacian(self) -> npt.NDArray[np.float64] | None:
        """L_Γ on the contact nodes in rank order, dense, on rank 0 (None elsewhere).

        For dense checks of the metric (tests, ``benchmarks/surface_metric.py``).
        """
        if self._rank0 is None:
            return None
        dense = self._rank0["laplacian"].convert("dense", out=None)
        try:
            return dense.getDenseArray().copy()
        finally:
            dense.destroy()

    def penalty_matrix(self, beta: float) -> PETSc.Mat:
        """Nᵀ(M + βL_Γ)N = K + β Nᵀ L_Γ N, in A's sparsity pattern (caller destroys it)."""
        problem = self.problem
        matrix = problem.A.duplicate(copy=False)
        matrix.zeroEntries()
        matrix.axpy(1.0, problem.K, structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN)
        matrix.axpy(
            beta, self.normal_stiffness, structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN
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
        node j that Dirichlet conditions prescribe (zero unless a condition fixes a
        component of a contact node's normal). Collective.

        Returns:
            Whether the lifting is non-zero anywhere (else ``out`` is left untouched).
        """
        problem, c = self.problem, self.problem.contact
        bs = problem.V.dofmap.index_map_bs
        values = problem.create_vector()
        try:
            values.set(0.0)
            fem_petsc.set_bc(values, problem.bcs)
            u_d = values.array_r.reshape(-1, bs)[c.nodes, : problem.gdim]
            d = np.einsum("ij,ij->i", u_d, c.normals - c.free_normals)
        finally:
            values.destroy()
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
        """Free the PETSc objects, the rank-0 copy of L_Γ included."""
        super().destroy()
        for vec in (*(getattr(self, "_work", None) or ()), getattr(self, "_force", None)):
            if vec is not None:
                vec.destroy()
        self._work = self._force = None
        if getattr(self, "_rank0", None) is not None:
            self._rank0["laplacian"].destroy()
            self._rank0 = None

    def projection(self, beta: float) -> SurfaceProjection:
        """The step-2 projection in the metric M + βL_Γ (caller destroys it); collective."""
        return SurfaceProjection(self, beta)


class SurfaceProjection(PetscOwner):
    """Steps 2–3 of ADMM in the metric R = r(M + βL_Γ): a QP on Γ_C, solved on rank 0.

    Args:
        metric: The surface metric.
        beta: β ≥ 0.
    """

    def __init__(self, metric: SurfaceMetric, beta: float):
        if not (math.isfinite(beta) and beta >= 0.0):
            raise ValueError(f"β must be finite and ≥ 0, got {beta!r}.")
        self.comm = metric.problem.comm
        self.layout = metric.layout
        self.beta = float(beta)

        def build() -> _ActiveSetQP:
            assert metric._rank0 is not None
            metric_matrix = metric._rank0["laplacian"].copy()
            metric_matrix.scale(beta)
            diagonal = metric_matrix.createVecLeft()
            diagonal.array[:] = metric._rank0["mass"]
            metric_matrix.setDiagonal(diagonal, addv=PETSc.InsertMode.ADD_VALUES)
            diagonal.destroy()
            return _ActiveSetQP(metric_matrix, metric._rank0["mass"])

        def failure(name: str, text: str, _: bool) -> Exception:
            return RuntimeError(f"Setting up the surface-metric projection failed: {name}: {text}")

        #: The QP on rank 0 (None elsewhere).
        self._qp: _ActiveSetQP | None = run_on_rank0(self.comm, build, failure, broadcast=False)

    def reset(self, gap: npt.NDArray[np.float64]) -> None:
        """Start a solve: the current gap (local part), and an empty contact set; collective."""
        g = self.layout.gather(gap)
        if self._qp is not None:
            self._qp.reset(g)

    def __call__(
        self,
        xi: npt.NDArray[np.float64],
        lam: npt.NDArray[np.float64],
        p: npt.NDArray[np.float64],
        normal: npt.NDArray[np.float64],
        r: float,
    ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        """Steps 2–3 from ξ, λ, and the equilibrium defect of step 1; collective.

        Args:
            xi: ξ = α N u + (1 − α) p (local part).
            lam: λ before the step.
            p: p before the step (the one step 1 used).
            normal: N u from step 1.
            r: The penalty.

        Returns:
            p⁺, λ⁺ and d = M⁻¹R(p − N u) + λ⁺ − λ, the equilibrium defect in pressure
            units (A u − f + NᵀMλ⁺ = NᵀM d), all local parts.

        Raises:
            RuntimeError: On every rank, if the active-set method does not terminate.
        """
        data = self.layout.gather(np.vstack([xi, lam, p, normal]))

        def step() -> npt.NDArray[np.float64]:
            assert self._qp is not None and data is not None
            return self._qp.step(*data, r)

        def failure(name: str, text: str, _: bool) -> Exception:
            return RuntimeError(f"The surface-metric projection (step 2) failed: {name}: {text}")

        # rank 0 solves; its failure is raised on every rank; the result is scattered
        out = run_on_rank0(self.comm, step, failure, broadcast=False)
        local = self.layout.scatter(out, 3)
        return local[0], local[1], local[2]

    def statistics(self) -> dict[str, int]:
        """Active-set rounds and factorisations (rank 0's sparse Cholesky) so far; collective."""
        counts = None
        if self._qp is not None:
            counts = {"rounds": self._qp.rounds, "factorisations": self._qp.factorisations}
        return self.comm.bcast(counts, root=0)

    def destroy(self) -> None:
        """Free the rank-0 matrices and factorisations."""
        if self._qp is not None:
            self._qp.destroy()
            self._qp = None


class _ActiveSetQP:
    """min ½(p − q)ᵀR̂(p − q) s.t. p ≤ g by primal-dual active sets (rank 0, sequential).

    R̂ = M + βL_Γ. The contact set 𝒜 of the previous call starts the next one; a
    factorisation of R̂ on the free nodes is kept while 𝒜 does not change.
    """

    def __init__(self, metric: PETSc.Mat, mass: npt.NDArray[np.float64]):
        self.R = metric
        self.mass = mass
        self.diagonal = metric.getDiagonal().array.copy()
        self.gap = np.zeros_like(mass)
        self.finite = np.ones(mass.size, dtype=bool)
        self.active = np.zeros(mass.size, dtype=bool)
        self._x, self._y = metric.createVecs()
        self._key: bytes | None = None
        self._ksp: PETSc.KSP | None = None
        self._sub: PETSc.Mat | None = None
        self._free_set: PETSc.IS | None = None
        self.rounds = 0
        self.factorisations = 0

    def reset(self, gap: npt.NDArray[np.float64]) -> None:
        self.gap = gap
        self.finite = np.isfinite(gap)
        self.active = np.zeros(gap.size, dtype=bool)

    def _mult(self, x: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        self._x.array[:] = x
        self.R.mult(self._x, self._y)
        return self._y.array.copy()

    def _solve_free(self, free: npt.NDArray[np.intp], rhs: npt.NDArray[np.float64]):
        key = free.tobytes()
        if key != self._key:
            for obj in (self._ksp, self._sub, self._free_set):
                if obj is not None:
                    obj.destroy()
            self._free_set = PETSc.IS().createGeneral(
                free.astype(PETSc.IntType), comm=PETSc.COMM_SELF
            )
            self._sub = self.R.createSubMatrix(self._free_set, self._free_set)
            self._ksp = PETSc.KSP().create(PETSc.COMM_SELF)
            self._ksp.setOperators(self._sub)
            self._ksp.setType(PETSc.KSP.Type.PREONLY)
            pc = self._ksp.getPC()
            pc.setType(PETSc.PC.Type.CHOLESKY)
            pc.setFactorOrdering(PETSc.Mat.OrderingType.ND)
            self._ksp.setUp()
            self._key = key
            self.factorisations += 1
        b, x = self._sub.createVecs()
        try:
            b.array[:] = rhs
            self._ksp.solve(b, x)
            if self._ksp.getConvergedReason() < 0:
                raise RuntimeError("the factorisation of M + βL_Γ on the free nodes failed")
            return x.array.copy()
        finally:
            b.destroy()
            x.destroy()

    def project(self, rq: npt.NDArray[np.float64]):
        """The minimiser p of ½ pᵀR̂p − pᵀ(R̂q) over p ≤ g, and μ = R̂(q − p) (0 off 𝒜)."""
        g, finite = self.gap, self.finite
        active = self.active & finite
        for _ in range(MAX_ACTIVE_SET_ROUNDS):
            self.rounds += 1
            p = np.where(active, g, 0.0)
            free = np.flatnonzero(~active)
            if free.size:
                rhs = rq - self._mult(p)
                p[free] = self._solve_free(free, rhs[free])
            mu = rq - self._mult(p)
            mu[free] = 0.0
            with np.errstate(invalid="ignore"):
                guess = finite & (mu + self.diagonal * (p - g) > 0.0)
            if np.array_equal(guess, active):
                self.active = active
                return p, mu
            active = guess
        raise RuntimeError(
            f"the active-set method did not settle in {MAX_ACTIVE_SET_ROUNDS} rounds "
            "(M + βL_Γ is not an M-matrix on this surface mesh); pass "
            "penalty_metric='mass' to ADMMSolver"
        )

    def step(self, xi, lam, p_in, normal, r):
        """(p⁺, λ⁺, d) of :meth:`SurfaceProjection.__call__`, on gathered arrays."""
        mass = self.mass
        rq = self._mult(xi) + mass * lam / r  # R̂ q = R̂ ξ + M λ / r
        p, mu = self.project(rq)
        lam_new = np.maximum(r * mu / mass, 0.0)
        defect = r * self._mult(p_in - normal) / mass + lam_new - lam
        return np.vstack([p, lam_new, defect])

    def destroy(self) -> None:
        for obj in (self._ksp, self._sub, self._free_set, self._x, self._y, self.R):
            if obj is not None:
                obj.destroy()
        self._ksp = self._sub = self._free_set = None
