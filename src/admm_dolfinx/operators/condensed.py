"""A + r NᵀMN through one factorisation of A condensed onto the contact dofs.

MUMPS factorises A, eliminating every dof except the set C that the contact normals
act on (the support of K = NᵀMN: at each contact node, the components in which its
normal ñ_j is non-zero), and returns the dense Schur complement

    S_C = A_CC − A_CI A_II⁻¹ A_IC        (c × c, c = |C| ≈ m, or gdim·m for curved Γ_C).

Since K lives on C × C, A + rK = [[A_II, A_IC], [A_CI, A_CC + r K_CC]] has the Schur
complement S_C + r K_CC, so

* a new r costs a dense c × c Cholesky factorisation, not a sparse one: a solve is
  MUMPS's condensation of the right-hand side, a dense solve, and MUMPS's expansion
  (PETSc's ``MatFactorSetSchurIS`` interface);
* the r* estimate reads the whole contact pencil off S_C densely (exact, see
  :func:`admm_dolfinx.penalty.dense.extremes_from_schur`).

Keeping C to the end constrains MUMPS's ordering (AMD, or METIS on large meshes:
:func:`condensed_ordering`, where A + rK gets AMF in 2D), which makes this
factorisation, and somewhat its substitutions, dearer than those of A + rK in 2D,
where C is a curve of O(n^½) dofs (``python benchmarks/penalty_cost.py`` prints both
factorisations and what the condensed path adds to a solve). In 3D C is a surface
of O(n^⅔) dofs, whose dense front of c³/3 flops dominates the factorisation, so
:func:`admm_dolfinx.penalty.estimate.estimate_penalty` and the solver use it in 2D,
and in 3D only for a small body that the contact alone holds, which polishing serves
(:func:`condensed_factor_applies`).

PETSc computes the Schur complement in parallel (all of C on rank 0), but solves with
it on one process only; under MPI the class serves the r* estimate and active-set
polishing (:mod:`admm_dolfinx.admm.polish_dense`), and the ADMM factorises A + r*K separately
(:attr:`CondensedOperator.can_solve`).
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
from dolfinx.common import Timer
from mpi4py import MPI
from petsc4py import PETSc

from admm_dolfinx._mpi import RankLayout, from_rank0, gather_concat, run_on_rank0
from admm_dolfinx.linalg.mumps_schur import (
    SchurBlock,
    factorize_schur,
    full_symmetric,
    set_schur_indices,
)
from admm_dolfinx.linalg.petsc import (
    check_solve,
    describe_factor_failure,
    describe_petsc_error,
    factor_options,
    is_factorisation,
    prefixed_options,
)
from admm_dolfinx.operators.penalised import FactorisedOperator
from admm_dolfinx.problem.contact_problem import ContactProblem

__all__ = [
    "CONDENSED_METIS_DOFS",
    "DENSE_COST_RATIO",
    "MAX_CONDENSED_CONTACT_NODES",
    "CondensedOperator",
    "ContactSupport",
    "condensed_factor_applies",
    "condensed_ordering",
]


# ---------------------------------------------------------------------------------
#: Above this many contact nodes the automatic choices leave the condensed
#: factorisation aside: S_C (up to 2m × 2m in 2D) would take over 250 MB and its dense
#: front would dominate the factorisation.
MAX_CONDENSED_CONTACT_NODES = 4000
#: The dense work on Γ_C grows like m³, a sparse factorisation of the 2D body like
#: n^{3/2}, the first at dense-BLAS speed: the condensed path is chosen while
#: m³ ≤ DENSE_COST_RATIO · n^{3/2}. At this ratio both paths cost the same on the
#: 20 × 0.1 strip with m = 1000 (``python benchmarks/strips.py`` times both); compact
#: bodies (m ≈ √n, the paper's Example 1) lie far on the dense side, thin ones with
#: thousands of contact nodes on the sparse side (sparse polishing,
#: :mod:`admm_dolfinx.admm.polish_sparse`).
DENSE_COST_RATIO = 300.0
#: MUMPS orders a factorisation with a Schur complement by AMD (AMF, the 2D ordering
#: of A + rK, is not available to it); from this many dofs on METIS is asked for
#: instead, whose fill grows more slowly: ``python benchmarks/scale_2d.py`` times the
#: condensed factorisation under both orderings at every size.
CONDENSED_METIS_DOFS = 500_000


def condensed_ordering(problem: ContactProblem, options: Mapping[str, Any] | None) -> dict:
    """MUMPS's ordering (``mat_mumps_icntl_7``) of the condensed factorisation.

    The caller's choice if ``options`` has one, else AMD (0) below
    :data:`CONDENSED_METIS_DOFS` dofs and METIS (5) from there on.
    """
    if options and "mat_mumps_icntl_7" in options:
        return {"mat_mumps_icntl_7": options["mat_mumps_icntl_7"]}
    n = problem.V.dofmap.index_map.size_global * problem.V.dofmap.index_map_bs
    return {"mat_mumps_icntl_7": 5 if n >= CONDENSED_METIS_DOFS else 0}


def condensed_factor_applies(
    problem: ContactProblem, options: Mapping[str, Any] | None, *, any_dimension: bool = False
) -> bool:
    """Whether :class:`CondensedOperator` applies (MUMPS; by default where it pays).

    By default: a 2D body, or a 3D body that the contact alone holds (a floating rigid
    motion), with at most :data:`MAX_CONDENSED_CONTACT_NODES` contact nodes and
    m³ ≤ :data:`DENSE_COST_RATIO` · n^{3/2} (n the number of dofs). A 3D body held
    elsewhere converges in a few iterations of the surface metric, where S_C of a
    surface costs more than it saves; a floating one, unpolished, builds its contact
    zone a few nodes per iteration. On a curved 3D Γ_C, C has up to 3m dofs, and the
    rule was checked there on the Hertz sphere, serially and on two processes, where
    it polishes the meshes on which polishing pays and not the first on which it does
    not (``python benchmarks/polish_3d.py --scene hertz_sphere``). In 3D the plan's
    choice of multigrid for large bodies (:mod:`admm_dolfinx.admm.plan`) bounds n
    first: then no factorisation is at hand and this returns False.

    Args:
        problem: The contact problem.
        options: The step-1 solver's options (they must keep a MUMPS factorisation).
        any_dimension: Accept any dimension and size (an explicit request: in 3D S_C is
            dense on a surface, which is costly).
    """
    if not is_factorisation(options or {}):
        return False
    if any_dimension:
        return True
    m = problem.contact.num_global
    n = problem.V.dofmap.index_map.size_global * problem.V.dofmap.index_map_bs
    return (
        (problem.gdim == 2 or problem.rigid_motions.floating > 0)
        and m <= MAX_CONDENSED_CONTACT_NODES
        and float(m) ** 3 <= DENSE_COST_RATIO * float(n) ** 1.5
    )


@dataclass
class ContactSupport:
    """The dof set C of K = NᵀMN and the pencil's data on it, on rank 0.

    Attributes:
        size: c = |C| (on every rank).
        dofs: Global indices of C, sorted (on rank 0; empty elsewhere).
        weights: W = Nᵀ M^{½} restricted to C, shape (c, m) (rank 0; None elsewhere):
            column j is node j's free normal ñ_j scaled by sqrt(M_jj).
    """

    size: int
    dofs: npt.NDArray[np.int32]
    weights: npt.NDArray[np.float64] | None

    @classmethod
    def build(cls, problem: ContactProblem) -> ContactSupport:
        """Gather C and W on rank 0; collective."""
        c = problem.contact
        bs = problem.V.dofmap.index_map_bs
        row0 = problem.A.getOwnershipRange()[0]
        ntilde = np.zeros((c.nodes.size, bs))
        ntilde[:, : problem.gdim] = c.free_normals
        node_of, comp = np.nonzero(ntilde)
        local = (
            (row0 + c.nodes[node_of] * bs + comp).astype(np.int64),
            node_of,
            ntilde[node_of, comp] * np.sqrt(c.mass[node_of]),
        )
        offset = RankLayout(problem.comm, c.nodes.size).start
        size = problem.comm.allreduce(local[0].size, op=MPI.SUM)
        gathered = gather_concat(problem.comm, local[0], local[1] + offset, local[2])
        if gathered is None:
            return cls(size, np.zeros(0, dtype=PETSc.IntType), None)
        dofs, rows, values = gathered
        unique, position = np.unique(dofs, return_inverse=True)
        weights = np.zeros((unique.size, c.num_global))
        weights[position, rows] = values
        return cls(size, unique.astype(PETSc.IntType), weights)


class CondensedOperator(FactorisedOperator):
    """A factorised once, with its dense Schur complement onto C; A + rK by dense updates.

    The interface of :class:`~admm_dolfinx.operators.penalised.PenalisedOperator` (``set_penalty``,
    ``solve``, ``penalty``, ``solves``, ``timings``, ``ksp``, ``destroy``).

    Args:
        problem: The contact problem.
        prefix: Options prefix of the KSP.
        petsc_options: KSP/PC options (a MUMPS factorisation; see
            :func:`condensed_factor_applies`).

    Attributes:
        support: C and the pencil's weights (rank 0).
        schur: S_C as a dense array on rank 0 (None elsewhere).
        k_cc: K = NᵀMN restricted to C × C, dense, on rank 0 (None elsewhere).
        can_solve: Whether :meth:`solve` is available (one process: PETSc solves with a
            Schur complement serially only).
    """

    def __init__(
        self,
        problem: ContactProblem,
        prefix: str,
        petsc_options: Mapping[str, Any] | None = None,
    ):
        options = factor_options(petsc_options, problem.gdim)
        if options.get("pc_factor_mat_solver_type") == "mumps":
            options.update(condensed_ordering(problem, petsc_options))
        if not is_factorisation(options):
            raise ValueError(
                "The condensed factorisation needs a MUMPS factorisation (ksp_type "
                "preonly, pc_type cholesky or lu, pc_factor_mat_solver_type mumps); "
                f"got {dict(petsc_options or {})}."
            )
        self.problem = problem
        self.prefix = prefix
        self.penalty = float("nan")
        self.solves = 0
        self.timings: dict[str, float] = {"operator": 0.0, "factorization": 0.0}
        self.can_solve = problem.comm.size == 1
        comm = problem.comm
        t0 = time.perf_counter()
        self.support = ContactSupport.build(problem)
        index_set = PETSc.IS().createGeneral(self.support.dofs, comm=comm)
        # MUMPS's symmetric Schur complement loses accuracy on badly scaled values (at
        # E = 1e-16, where LU and the plain Cholesky stay exact:
        # tests/reliability/test_wrong_answers.py::test_scale_invariance): it
        # factorises A / s, s the stiffness scale, and the values are scaled back here.
        self._scale = problem.stiffness_scale
        self.matrix = problem.A.duplicate(copy=True)
        self.matrix.scale(1.0 / self._scale)
        self.matrix.setOption(PETSc.Mat.Option.SPD, True)
        self.ksp = PETSc.KSP().create(comm)
        self.factor: PETSc.Mat | None = None
        self.schur: npt.NDArray[np.float64] | None = None
        self.k_cc: npt.NDArray[np.float64] | None = None
        try:
            with Timer("admm_dolfinx: factorisation (A condensed onto Γ_C)"):
                self.ksp.setOperators(self.matrix)
                self.ksp.setOptionsPrefix(prefix)
                database = PETSc.Options()
                with prefixed_options(prefix, options):
                    try:
                        self.ksp.setFromOptions()
                        self.ksp.getPC().setFactorSetUpSolverType()
                        self.factor = self.ksp.getPC().getFactorMatrix()
                        set_schur_indices(self.factor, index_set)
                        self.ksp.setUp()
                    except PETSc.Error as error:
                        raise RuntimeError(
                            f"PETSc could not factorise A condensed onto Γ_C (prefix "
                            f"{prefix!r}, options {options}): {describe_petsc_error(error)}."
                        ) from error
                    unused = [k for k in options if not database.used(f"{prefix}{k}")]
                if unused:
                    raise ValueError(
                        f"PETSc did not use the option(s) {unused} of the step-1 solver "
                        f"(prefix {prefix!r}): misspelt, or meant for another solver."
                    )
                self._check_factorisation()
            # K_CC: the ADMM's K restricted to C (a sequential matrix on every rank)
            k_sub = problem.K.createSubMatrices(index_set, index_set)[0]
            try:

                def read() -> tuple[np.ndarray, np.ndarray]:
                    with SchurBlock(self.factor) as block:
                        schur = self._scale * full_symmetric(block.T, serial=comm.size == 1)
                    return schur, k_sub.convert("dense").getDenseArray().copy()

                def failure(name: str, text: str, _: bool) -> Exception:
                    return RuntimeError(f"Reading the Schur complement S_C failed: {name}: {text}")

                dense = run_on_rank0(comm, read, failure, broadcast=False)
                if dense is not None:
                    self.schur, self.k_cc = dense
            finally:
                k_sub.destroy()
            self._check_support()
        except BaseException:
            self.destroy()
            raise
        finally:
            index_set.destroy()
        self.timings["factorization"] = time.perf_counter() - t0

    def _check_factorisation(self) -> None:
        failure = describe_factor_failure(self.ksp)
        if failure is not None:
            raise RuntimeError(f"The factorisation of A condensed onto Γ_C failed: {failure}.")

    def _check_support(self) -> None:
        """K must vanish outside C × C, or the condensed solve would be wrong."""
        total = self.problem.K.norm(PETSc.NormType.FROBENIUS)
        inside = float(np.linalg.norm(self.k_cc)) if self.k_cc is not None else 0.0
        inside = from_rank0(self.problem.comm, inside)
        if abs(total - inside) > 1e-12 * max(total, 1e-300):  # pragma: no cover - invariant
            raise RuntimeError("NᵀMN has entries outside the contact normal dofs.")

    def set_penalty(self, r: float) -> None:
        """Make the solver solve with A + rK: a dense Cholesky of S_C + r K_CC.

        Args:
            r: Penalty parameter (> 0; the caller validates user input).
        """
        if r == self.penalty:
            return
        if not self.can_solve:
            raise RuntimeError(
                "Solving with the condensed factorisation needs one process (PETSc "
                "solves with a Schur complement serially only); under MPI use "
                "PenalisedOperator."
            )
        # one process (can_solve): rank 0 holds S_C and K_CC
        assert self.schur is not None and self.k_cc is not None
        with Timer("admm_dolfinx: factorisation (S_C + r K_CC)"):
            t0 = time.perf_counter()
            with SchurBlock(self.factor) as block:
                # the whole symmetric matrix: right whichever triangle MUMPS filled
                block[:] = (self.schur + r * self.k_cc) / self._scale
            factorize_schur(self.factor)
            self.timings["operator"] = time.perf_counter() - t0
        self.penalty = float(r)

    def solve(self, b: PETSc.Vec, x: PETSc.Vec) -> None:
        """Solve (A + rK) x = b: condensation, dense solve, expansion."""
        if not self.penalty == self.penalty:  # NaN: no r yet
            raise RuntimeError("set_penalty must be called before solve.")
        ksp = self._factorisation()
        ksp.solve(b, x)
        x.scale(1.0 / self._scale)  # (A + rK)⁻¹ = ((A + rK) / s)⁻¹ / s
        self.solves += 1
        check_solve(ksp, f"A + r NᵀMN at r = {self.penalty:.6g} (condensed)")

    def destroy(self) -> None:
        """Free the KSP (with the factors) and the matrix."""
        factor = getattr(self, "factor", None)
        if factor is not None:
            factor.destroy()  # our reference: the KSP's release then frees MUMPS
            self.factor = None
        super().destroy()
