"""Steps 2–3 of ADMM in the surface metric R = r(M + βL_Γ): a QP on Γ_C, on rank 0.

In the metric R (:mod:`admm_dolfinx.linalg.surface_metric`) ADMM's steps read

    (A + NᵀR N) u = f + Nᵀ (R p − M λ)                      step 1 (stored factors)
    p⁺ = argmin_{p ≤ g} ½ (p − q)ᵀ R (p − q),  R q = R ξ + M λ   step 2: a QP on Γ_C
    λ⁺ = M⁻¹ R (q − p⁺)                                     step 3: its multiplier

Step 2 is no longer node-wise; it is a bound-constrained QP on the contact surface
(m unknowns, a sparse surface matrix), solved exactly on rank 0 by a primal-dual
active-set method warm-started from the previous iteration's contact set (one sparse
Cholesky factorisation per change of the set). λ⁺ ≥ 0 and λ⁺(g − p⁺) = 0 hold by
construction. With β = 0 it is the paper's step 2 and 3 exactly.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
from petsc4py import PETSc

from admm_dolfinx._mpi import from_rank0, run_on_rank0
from admm_dolfinx.linalg.petsc import PetscOwner
from admm_dolfinx.linalg.surface_metric import SurfaceMetric

__all__ = ["MAX_ACTIVE_SET_ROUNDS", "SurfaceProjection"]

#: Rounds of the active-set method per projection before it gives up. With a warm
#: start it needs few (``result.projection`` counts them); it is finite for M-matrices
#: and in practice for any mesh.
MAX_ACTIVE_SET_ROUNDS = 100


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
            assert g is not None  # the QP and the gathered gap are both on rank 0
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
            return self._qp.step(data[0], data[1], data[2], data[3], r)

        def failure(name: str, text: str, _: bool) -> Exception:
            return RuntimeError(f"The surface-metric projection (step 2) failed: {name}: {text}")

        # rank 0 solves; its failure is raised on every rank; the result is scattered
        out = run_on_rank0(self.comm, step, failure, broadcast=False)
        local = self.layout.scatter(out, 3)
        return local[0], local[1], local[2]

    def statistics(self) -> dict[str, int] | None:
        """Active-set rounds and factorisations (rank 0's sparse Cholesky) so far; collective.

        Returns:
            The counts on every rank (None once the projection is destroyed).
        """
        counts: dict[str, int] | None = None
        if self._qp is not None:
            counts = {"rounds": self._qp.rounds, "factorisations": self._qp.factorisations}
        return from_rank0(self.comm, counts)

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

    def _solve_free(
        self, free: npt.NDArray[np.intp], rhs: npt.NDArray[np.float64]
    ) -> npt.NDArray[np.float64]:
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
        ksp, sub = self._ksp, self._sub
        assert ksp is not None and sub is not None  # made above for this free set
        b, x = sub.createVecs()
        try:
            b.array[:] = rhs
            ksp.solve(b, x)
            if ksp.getConvergedReason() < 0:
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

    def step(
        self,
        xi: npt.NDArray[np.float64],
        lam: npt.NDArray[np.float64],
        p_in: npt.NDArray[np.float64],
        normal: npt.NDArray[np.float64],
        r: float,
    ) -> npt.NDArray[np.float64]:
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
