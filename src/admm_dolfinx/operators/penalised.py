"""The factorised penalised stiffness A_r = A + r NᵀMN, shared by ADMM and r*.

One :class:`PenalisedOperator` holds one matrix and one KSP. Changing r keeps the
sparsity pattern, so PETSc/MUMPS redo only the *numeric* factorisation and reuse the
symbolic analysis. The ADMM solver and the eigenvalue estimate of r* use the same
instance, so computing r* costs no extra symbolic factorisation of A_r.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from typing import Any

from dolfinx.common import Timer
from petsc4py import PETSc

from admm_dolfinx.linalg.galerkin import CoarsePenalty
from admm_dolfinx.linalg.petsc import (
    PetscOwner,
    check_solve,
    create_factor_solver,
    prefixed_options,
)
from admm_dolfinx.linalg.smoothers import solve_spd
from admm_dolfinx.problem.contact_problem import ContactProblem

__all__ = ["MAX_KRYLOV_ITERATIONS", "FactorisedOperator", "IterativeOperator", "PenalisedOperator"]

#: The iteration limit of an iterative step-1 solve (unless ``ksp_max_it`` is given).
MAX_KRYLOV_ITERATIONS = 1000


class FactorisedOperator(PetscOwner):
    """Owns a matrix and the KSP that factorises it; frees both (the step-1 operators)."""

    _petsc_objects = ("ksp", "matrix")
    matrix: PETSc.Mat | None = None
    ksp: PETSc.KSP | None = None

    def _factorisation(self) -> PETSc.KSP:
        """The KSP holding the factorisation.

        Raises:
            RuntimeError: If there is none yet (no :meth:`set_penalty`), or the operator
                was destroyed.
        """
        if self.ksp is None:
            raise RuntimeError(
                f"{type(self).__name__} has no factorisation: call set_penalty() first "
                "(or it was destroyed)."
            )
        return self.ksp


class PenalisedOperator(FactorisedOperator):
    """A + r NᵀMN with a reusable factorisation.

    Args:
        problem: The contact problem (provides A and K = NᵀMN).
        prefix: Options prefix of the KSP.
        petsc_options: KSP/PC options overriding MUMPS Cholesky.

    Attributes:
        penalty: Current r (NaN before the first :meth:`set_penalty`).
        solves: Number of :meth:`solve` calls so far.
        timings: Seconds of the last ``operator`` build and ``factorization`` (of the
            iterative operator: the preconditioner's set-up), and of the multigrid
            ``hierarchy`` built on A (:meth:`IterativeOperator.set_up_hierarchy`; 0 if
            none was).
    """

    def __init__(
        self,
        problem: ContactProblem,
        prefix: str,
        petsc_options: Mapping[str, Any] | None = None,
    ):
        self.problem = problem
        self.gdim = problem.mesh.geometry.dim
        self.prefix = prefix
        self._options = dict(petsc_options or {})
        self.matrix: PETSc.Mat | None = None
        self.ksp: PETSc.KSP | None = None
        self.penalty = float("nan")
        self.solves = 0
        #: Seconds spent in :meth:`solve` so far.
        self.solve_time = 0.0
        self.timings: dict[str, float] = {"operator": 0.0, "factorization": 0.0, "hierarchy": 0.0}
        self._label = "A + r NᵀMN"
        self._penalty_matrix: PETSc.Mat | None = None
        self._penalty_name = "NᵀMN"

    def use_penalty_matrix(self, matrix: PETSc.Mat, name: str) -> None:
        """Penalise with ``matrix`` instead of K = NᵀMN from the next :meth:`set_penalty` on.

        Args:
            matrix: Symmetric positive semi-definite, its pattern within A's (e.g.
                Nᵀ(M + βL_Γ)N of :mod:`admm_dolfinx.operators.surface_metric`); the operator
                takes ownership.
            name: What it is, for labels (``"Nᵀ(M + βL_Γ)N"``).
        """
        if self._penalty_matrix is not None:
            self._penalty_matrix.destroy()
        self._penalty_matrix = matrix
        self._penalty_name = name
        self.penalty = float("nan")  # the next set_penalty refactorises

    def destroy(self) -> None:
        """Free the matrix, the KSP and a penalty matrix given to :meth:`use_penalty_matrix`."""
        super().destroy()
        if self._penalty_matrix is not None:
            self._penalty_matrix.destroy()
            self._penalty_matrix = None

    def set_penalty(self, r: float) -> None:
        """Form A + rK and factorise it (numeric only, after the first time).

        Args:
            r: Penalty parameter (≥ 0; the caller validates user input).
        """
        if r == self.penalty:
            return
        matrix = self._form(r)
        with Timer("admm_dolfinx: factorisation"):
            t0 = time.perf_counter()
            self._ensure_ksp(matrix).setUp()
            self.timings["factorization"] = time.perf_counter() - t0
        self.penalty = float(r)
        self._label = f"A + r {self._penalty_name} at r = {r:.6g}"

    def _penalty(self) -> PETSc.Mat:
        """K: NᵀMN, or the matrix given to :meth:`use_penalty_matrix`."""
        return self.problem.K if self._penalty_matrix is None else self._penalty_matrix

    def _form(self, r: float) -> PETSc.Mat:
        """Set :attr:`matrix` to A + rK (created on the first call) and return it."""
        A, K = self.problem.A, self._penalty()
        with Timer("admm_dolfinx: operator A + rK"):
            t0 = time.perf_counter()
            if self.matrix is None:
                self.matrix = A.duplicate(copy=True)
                self.matrix.setOption(PETSc.Mat.Option.SPD, True)
                # duplicate() drops the rigid-body near null space that multigrid needs
                self.matrix.setNearNullSpace(A.getNearNullSpace())
            else:
                A.copy(self.matrix, structure=PETSc.Mat.Structure.SAME_NONZERO_PATTERN)
            matrix = self.matrix
            matrix.axpy(r, K, structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN)
            self.timings["operator"] = time.perf_counter() - t0
        return matrix

    def _ensure_ksp(self, matrix: PETSc.Mat) -> PETSc.KSP:
        """Create the KSP (factorising), or tell it that the matrix values changed.

        Args:
            matrix: The operator's matrix (:attr:`matrix`), its values set.

        Returns:
            The KSP.
        """
        if self.ksp is None:
            self.ksp = create_factor_solver(matrix, self.prefix, self._options, self.gdim)
        else:
            self.ksp.setOperators(matrix)
        return self.ksp

    def load(self, values: PETSc.Mat, label: str) -> None:
        """Factorise another SPD matrix whose pattern is a subset of A's (numeric only).

        Used by the r* estimate to factorise the projected stiffness in the same
        matrix, so the symbolic analysis is shared by every factorisation.

        Args:
            values: The matrix; its sparsity pattern must be contained in A's.
            label: What it is, for timers and error messages.
        """
        if self.matrix is None:
            self.matrix = self.problem.A.duplicate(copy=False)
            self.matrix.setOption(PETSc.Mat.Option.SPD, True)
        matrix = self.matrix
        matrix.zeroEntries()
        matrix.axpy(1.0, values, structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN)
        with Timer(f"admm_dolfinx: factorisation ({label})"):
            self._ensure_ksp(matrix).setUp()
        self.penalty = float("nan")
        self._label = label

    def solve(self, b: PETSc.Vec, x: PETSc.Vec) -> None:
        """Solve (A + rK) x = b with the stored factorisation."""
        assert self.ksp is not None, "set_penalty must be called first"
        t0 = time.perf_counter()
        self.ksp.solve(b, x)
        self.solve_time += time.perf_counter() - t0
        self.solves += 1
        check_solve(self.ksp, self._label)


class IterativeOperator(PenalisedOperator):
    """A + r NᵀMN solved by a Krylov method, warm-started, to a tolerance set per solve.

    The step 1 of the multigrid path: conjugate gradients preconditioned by
    smoothed-aggregation multigrid (PETSc ``PCGAMG``) with the rigid body modes that the
    problem attaches to A as near null space, unless the options say otherwise. The
    preconditioner is set up once per r (in :meth:`set_penalty`) and reused by every
    solve at that r, across iterations and load steps. Each solve starts from the
    vector it is given (the previous displacement) and stops at the relative residual
    :meth:`set_tolerance` last set: the inexact ADMM of
    :mod:`admm_dolfinx.admm.inexact` chooses it.

    A solve that reaches its iteration limit is counted in :attr:`unconverged` (the
    ADMM's final check of the KKT residuals judges the answer); a breakdown (an
    indefinite preconditioner, NaN) raises.

    Attributes:
        iterations: Krylov iterations of every solve so far.
        last_iterations: Krylov iterations of the last solve.
        unconverged: Solves that stopped at their iteration limit.
        careful_bounds: Solves that found the multigrid indefinite and made its
            smoothers' eigenvalue bounds careful.
        rtol: The relative tolerance of the next solve.
    """

    def __init__(
        self,
        problem: ContactProblem,
        prefix: str,
        petsc_options: Mapping[str, Any] | None = None,
    ):
        super().__init__(problem, prefix, petsc_options)
        self.iterations = 0
        self.last_iterations = 0
        self.unconverged = 0
        #: Solves after which the multigrid's smoothers were made careful.
        self.careful_bounds = 0
        self.rtol = 1e-8
        self._coarse: CoarsePenalty | None = None

    def destroy(self) -> None:
        """Free the matrix, the KSP, the penalty matrix and the projected penalties."""
        if self._coarse is not None:
            self._coarse.destroy()
            self._coarse = None
        super().destroy()

    def set_penalty(self, r: float) -> None:
        """Form A + rK and set the preconditioner up for it.

        The first call sets the multigrid up (hierarchy and coarse operators). Later
        ones, when the hierarchy is kept (GAMG with ``pc_gamg_reuse_interpolation``,
        the default), move the coarse operators to the new r as A_l + r K_l
        (:mod:`admm_dolfinx.linalg.galerkin`) instead of recomputing the Galerkin
        products; otherwise PETSc sets the preconditioner up again.

        Args:
            r: Penalty parameter (≥ 0; the caller validates user input).
        """
        if r == self.penalty:
            return
        coarse = self._coarse
        if coarse is None:
            super().set_penalty(r)
            pc = self._factorisation().getPC()
            if pc.getType() == PETSc.PC.Type.GAMG and _keeps_hierarchy(self._options):
                self._coarse = CoarsePenalty(pc, self._penalty(), r)
            return
        matrix = self._form(r)
        with Timer("admm_dolfinx: multigrid coarse operators A_l + r K_l"):
            t0 = time.perf_counter()
            # the smoothers are set up again: with the step-1 options (a user's
            # mg_levels_* among them), as PETSc's own set-up would read them
            with prefixed_options(self.prefix, self._options):
                coarse.move(matrix, r)
            self.timings["factorization"] = time.perf_counter() - t0
        self.penalty = float(r)
        self._label = f"A + r {self._penalty_name} at r = {r:.6g}"

    def use_penalty_matrix(self, matrix: PETSc.Mat, name: str) -> None:
        """As :meth:`PenalisedOperator.use_penalty_matrix`; the coarse operators follow."""
        super().use_penalty_matrix(matrix, name)
        if self._coarse is not None and not self._coarse.change_matrix(matrix):
            self._drop_coarse()

    def load(self, values: PETSc.Mat, label: str) -> None:
        """As :meth:`PenalisedOperator.load`, the preconditioner set up afresh."""
        self._drop_coarse()
        super().load(values, label)

    def _drop_coarse(self) -> None:
        """Let PETSc set the preconditioner up at the next change of the matrix."""
        if self._coarse is not None:
            self._coarse.pc.setReusePreconditioner(False)
            self._coarse.destroy()
            self._coarse = None

    def set_up_hierarchy(self) -> PETSc.PC | None:
        """Set the preconditioner up on A itself, before r is known; collective.

        Call it once, first: after a :meth:`set_penalty` the kept interpolation would
        be reused, not rebuilt on A.

        The multigrid hierarchy (aggregates, smoothed interpolation) is the dear part
        of the set-up, and r changes little of it: built on A (r = 0) and kept by
        every later :meth:`set_penalty` (``pc_gamg_reuse_interpolation``,
        :data:`~admm_dolfinx.linalg.petsc.GAMG_KEEP_HIERARCHY`), which moves only the
        coarse operators to A_l + r K_l (:mod:`admm_dolfinx.linalg.galerkin`).
        Meanwhile the r* estimate preconditions its λ_max eigensolve with it, instead
        of building a hierarchy of its own (``python benchmarks/scale_3d.py`` times both set-ups).

        Returns:
            The preconditioner (this operator's; valid until its next
            :meth:`set_penalty`), or None if the options chose no multigrid.
        """
        t0 = time.perf_counter()
        self.set_penalty(0.0)
        self.timings["hierarchy"] = time.perf_counter() - t0
        self.timings["factorization"] = 0.0
        pc = self._factorisation().getPC()
        return pc if pc.getType() == PETSc.PC.Type.GAMG else None

    def multigrid_at(self, r: float) -> PETSc.PC | None:
        """Set the penalty to r and return the multigrid of A + rK; collective.

        For a floating body, whose A alone is singular: r*'s λ_max preconditions
        with it at its auxiliary r_a. Valid until the next :meth:`set_penalty`.

        Returns:
            The preconditioner (this operator's), or None if the options chose no
            multigrid.
        """
        self.set_penalty(r)
        pc = self._factorisation().getPC()
        return pc if pc.getType() == PETSc.PC.Type.GAMG else None

    def set_tolerance(self, rtol: float) -> None:
        """Relative residual tolerance of the next solves."""
        self.rtol = float(rtol)
        if self.ksp is not None:
            self.ksp.setTolerances(rtol=self.rtol)

    def _ensure_ksp(self, matrix: PETSc.Mat) -> PETSc.KSP:
        fresh = self.ksp is None
        ksp = super()._ensure_ksp(matrix)
        if fresh:
            ksp.setInitialGuessNonzero(True)
            if "ksp_max_it" not in self._options:
                # a solve asked for a tolerance at round-off may stagnate: it is then
                # counted as unconverged, and the KKT check judges the answer
                ksp.setTolerances(max_it=MAX_KRYLOV_ITERATIONS)
            if "ksp_divtol" not in self._options:
                # a warm start leaves a tiny initial residual, which CG's residual may
                # exceed many times over on its way down: not a divergence
                ksp.setTolerances(divtol=1e300)
        ksp.setTolerances(rtol=self.rtol)
        return ksp

    def solve(self, b: PETSc.Vec, x: PETSc.Vec) -> None:
        """Solve (A + rK) x = b from the initial guess x, to :attr:`rtol`.

        A multigrid found indefinite has its smoothers' bounds estimated carefully and
        the system solved again (:func:`~admm_dolfinx.linalg.smoothers.solve_spd`;
        counted in :attr:`careful_bounds`).
        """
        ksp = self._factorisation()
        t0 = time.perf_counter()
        with prefixed_options(self.prefix, self._options):  # as at a new r
            ours = "ksp_max_it" not in self._options
            if solve_spd(ksp, b, x, f"step 1 ({self._label})", limit_is_ours=ours):
                self.careful_bounds += 1
        self.solve_time += time.perf_counter() - t0
        self.solves += 1
        self.last_iterations = ksp.getIterationNumber()
        self.iterations += self.last_iterations
        reason = ksp.getConvergedReason()
        if reason == PETSc.KSP.ConvergedReason.DIVERGED_MAX_IT:
            self.unconverged += 1
            return
        check_solve(ksp, self._label)


def _keeps_hierarchy(options: Mapping[str, Any]) -> bool:
    """Whether the options keep GAMG's hierarchy across values (``pc_gamg_reuse_interpolation``)."""
    value = options.get("pc_gamg_reuse_interpolation", False)
    return value is None or str(value).lower() in ("1", "true", "yes", "on")
