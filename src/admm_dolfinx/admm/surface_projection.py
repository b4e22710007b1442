"""Steps 2–3 of ADMM in the surface metric R = r(M + βL_Γ): a QP on Γ_C, distributed.

In the metric R (:mod:`admm_dolfinx.operators.surface_metric`) ADMM's steps read

    (A + NᵀR N) u = f + Nᵀ (R p − M λ)                      step 1 (stored factors)
    p⁺ = argmin_{p ≤ g} ½ (p − q)ᵀ R (p − q),  R q = R ξ + M λ   step 2: a QP on Γ_C
    λ⁺ = M⁻¹ R (q − p⁺)                                     step 3: its multiplier

Step 2 is no longer node-wise; it is a bound-constrained QP on the contact surface
(m unknowns, a sparse surface matrix), solved exactly by a primal-dual active-set
method warm-started from the previous iteration's contact set: each round solves
R̂_FF p_F = (R̂ q − R̂_FA g_A)_F on the free nodes F with one sparse Cholesky
factorisation per change of the set, numeric only: R̂_FF is factorised inside R̂'s
pattern (the active rows and columns reduced to their diagonal), so the ordering and
symbolic factorisation are made once. Everything is distributed over the ranks that own
contact nodes, in the layout of the contact m-vectors: R̂ = M + βL_Γ is an MPI matrix,
the free-set solves are MUMPS's (PETSc's own Cholesky on one process), and the
active-set test is agreed over the ranks. The iterates are those of the serial method,
to round-off. λ⁺ ≥ 0 and λ⁺(g − p⁺) = 0 hold by construction. With β = 0 it is the
paper's step 2 and 3 exactly.
"""

from __future__ import annotations

import hashlib
import math

import numpy as np
import numpy.typing as npt
from mpi4py import MPI
from petsc4py import PETSc

from admm_dolfinx.linalg.petsc import PetscOwner, apply_options, describe_petsc_error
from admm_dolfinx.operators.surface_metric import SurfaceMetric

__all__ = ["MAX_ACTIVE_SET_ROUNDS", "SurfaceProjection"]

#: Rounds of the active-set method per projection before it gives up. With a warm
#: start it needs few (``result.projection`` counts them); it is finite for M-matrices
#: and in practice for any mesh.
MAX_ACTIVE_SET_ROUNDS = 100
_WHAT = "the surface-metric projection (step 2: M + βL_Γ on the free contact nodes)"


class SurfaceProjection(PetscOwner):
    """Steps 2–3 of ADMM in the metric R = r(M + βL_Γ): a QP on Γ_C; collective.

    min ½(p − q)ᵀR̂(p − q) s.t. p ≤ g, R̂ = M + βL_Γ, by primal-dual active sets. The
    contact set 𝒜 of the previous call starts the next one; the factorisation of R̂ on
    the free nodes is kept while 𝒜 does not change on any rank.

    Args:
        metric: The surface metric.
        beta: β ≥ 0.
        prefix: Options prefix of the free-set factorisations (a Cholesky KSP: MUMPS on
            several processes, PETSc's own on one); options under it in PETSc's options
            database override these (the solver's ``petsc_options`` are step 1's and do
            not reach it).
    """

    _petsc_objects = ("_ksp", "_free_matrix", "_x", "_y", "R")

    def __init__(self, metric: SurfaceMetric, beta: float, prefix: str):
        if not (math.isfinite(beta) and beta >= 0.0):
            raise ValueError(f"β must be finite and ≥ 0, got {beta!r}.")
        self.comm = metric.problem.comm
        self.prefix = prefix
        self.beta = float(beta)
        mass = metric.problem.contact.mass
        self.mass = mass
        self._ksp: PETSc.KSP | None = None
        self._free_matrix: PETSc.Mat | None = None
        #: R̂ = M + βL_Γ on the contact nodes (distributed like the m-vectors).
        self.R = metric.contact_laplacian.copy()
        self.R.scale(self.beta)
        self._x, self._y = self.R.createVecs()
        self._x.array[:] = mass
        self.R.setDiagonal(self._x, addv=PETSc.InsertMode.ADD_VALUES)
        diagonal = self.R.getDiagonal()
        self.diagonal = diagonal.array.copy()
        diagonal.destroy()
        self.start = self.R.getOwnershipRange()[0]
        self.gap = np.zeros_like(mass)
        self.finite = np.ones(mass.size, dtype=bool)
        self.active = np.zeros(mass.size, dtype=bool)
        self._key: bytes | None = None
        self.rounds = 0
        self.factorisations = 0

    def reset(self, gap: npt.NDArray[np.float64]) -> None:
        """Start a solve: the current gap (local part), and an empty contact set."""
        self.gap = np.asarray(gap, dtype=np.float64)
        self.finite = np.isfinite(self.gap)
        self.active = np.zeros(self.gap.size, dtype=bool)

    def _mult(self, x: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        """R̂ x (local parts); collective."""
        self._x.array[:] = x
        self.R.mult(self._x, self._y)
        return self._y.array.copy()

    def _factorise(self, free: npt.NDArray[np.intp]) -> None:
        """Factorise R̂ on the free nodes, unless the free set is unchanged everywhere.

        The factorised matrix is R̂ with the rows and columns of the active nodes
        replaced by their diagonal: R̂_FF on the free nodes, decoupled from the rest,
        in R̂'s pattern whatever the set. So the ordering and symbolic factorisation are
        made once per projection and each change of the set refactorises numerically.
        """
        digest = hashlib.sha1(free.tobytes()).digest()
        changed = self.comm.allreduce(digest != self._key, op=MPI.LOR)
        if not changed:
            return
        active = np.ones(self.diagonal.size, dtype=bool)
        active[free] = False
        first = self._ksp is None
        if first:
            self._free_matrix = self.R.duplicate(copy=True)
            self._free_matrix.setOption(PETSc.Mat.Option.KEEP_NONZERO_PATTERN, True)
        else:
            self.R.copy(self._free_matrix, structure=PETSc.Mat.Structure.SAME_NONZERO_PATTERN)
        matrix = self._free_matrix
        assert matrix is not None  # made on the first call
        rows = (self.start + np.flatnonzero(active)).astype(PETSc.IntType)
        matrix.zeroRowsColumns(rows, diag=1.0)
        self._x.array[:] = self.diagonal  # active rows keep R̂'s scale
        matrix.setDiagonal(self._x, addv=PETSc.InsertMode.INSERT_VALUES)
        matrix.setOption(PETSc.Mat.Option.SPD, True)  # after the changes of values
        if first:
            self._ksp = PETSc.KSP().create(self.comm)
            self._ksp.setOperators(self._free_matrix)
            self._ksp.setType(PETSc.KSP.Type.PREONLY)
            pc = self._ksp.getPC()
            pc.setType(PETSc.PC.Type.CHOLESKY)
            if self.comm.size > 1:
                pc.setFactorSolverType("mumps")
            else:  # one process: PETSc's own sparse Cholesky, nested-dissection ordered
                pc.setFactorOrdering(PETSc.Mat.OrderingType.ND)
            # the user's options under the prefix win; a failure names the prefix
            apply_options(self._ksp, self.prefix, {}, setup=True, what=_WHAT)
        else:
            assert self._ksp is not None
            self._ksp.setOperators(self._free_matrix)  # new values, the same pattern
            try:
                self._ksp.setUp()
            except PETSc.Error as error:
                raise RuntimeError(
                    f"PETSc could not factorise {_WHAT} (options prefix {self.prefix!r}): "
                    f"{describe_petsc_error(error)}."
                ) from error
        self._key = digest
        self.factorisations += 1

    def _solve_free(
        self, free: npt.NDArray[np.intp], rhs: npt.NDArray[np.float64]
    ) -> npt.NDArray[np.float64]:
        """R̂_FF⁻¹ rhs on the free nodes (local parts); collective."""
        self._factorise(free)
        ksp = self._ksp
        assert ksp is not None  # made for this free set
        self._x.set(0.0)
        self._x.array[free] = rhs
        ksp.solve(self._x, self._y)
        if ksp.getConvergedReason() < 0:
            raise RuntimeError(
                "the surface-metric projection (step 2) failed: the factorisation of "
                "M + βL_Γ on the free nodes failed"
            )
        return self._y.array[free].copy()

    def project(self, rq: npt.NDArray[np.float64]):
        """The minimiser p of ½ pᵀR̂p − pᵀ(R̂q) over p ≤ g, and μ = R̂(q − p) (0 off 𝒜)."""
        g, finite = self.gap, self.finite
        active = self.active & finite
        for _ in range(MAX_ACTIVE_SET_ROUNDS):
            self.rounds += 1
            p = np.where(active, g, 0.0)
            free = np.flatnonzero(~active)
            rhs = rq - self._mult(p)
            if self.comm.allreduce(free.size, op=MPI.SUM):  # some node is free somewhere
                p[free] = self._solve_free(free, rhs[free])
            mu = rq - self._mult(p)
            mu[free] = 0.0
            with np.errstate(invalid="ignore"):
                guess = finite & (mu + self.diagonal * (p - g) > 0.0)
            if self.comm.allreduce(bool(np.array_equal(guess, active)), op=MPI.LAND):
                self.active = active
                return p, mu
            active = guess
        raise RuntimeError(
            f"the active-set method did not settle in {MAX_ACTIVE_SET_ROUNDS} rounds "
            "(M + βL_Γ is not an M-matrix on this surface mesh); pass "
            "expert={'penalty_metric': 'mass'} to ADMMSolver"
        )

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
        mass = self.mass
        rq = self._mult(xi) + mass * lam / r  # R̂ q = R̂ ξ + M λ / r
        p_new, mu = self.project(rq)
        lam_new = np.maximum(r * mu / mass, 0.0)
        defect = r * self._mult(p - normal) / mass + lam_new - lam
        return p_new, lam_new, defect

    def statistics(self) -> dict[str, int]:
        """Active-set rounds and factorisations so far (the same on every rank)."""
        return {"rounds": self.rounds, "factorisations": self.factorisations}
