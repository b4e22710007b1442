"""The coarse operators of a kept multigrid hierarchy of A + rK, formed as A_l + r K_l.

The Galerkin coarse operator of level l is P_lᵀ (A + rK) P_l, with P_l the
interpolation from level l to the fine grid: it is linear in r,

    P_lᵀ (A + rK) P_l = A_l + r K_l,     K_l = P_lᵀ K P_l.

With the hierarchy kept across values of r (``pc_gamg_reuse_interpolation``), PETSc
still recomputes every product P_lᵀ (A + rK) P_l for a new r, and those products are
most of the set-up. K (NᵀMN, or Nᵀ(M + βL_Γ)N) lives on the contact boundary, so its
products K_l are cheap: :class:`CoarsePenalty` computes them once per penalty matrix
and moves each coarse operator to a new r by adding (r − r_old) K_l in place. The
level smoothers (Chebyshev's eigenvalue bounds, Jacobi's diagonal) and the coarse
solve are then set up again on the new operators, as PETSc's own set-up would, and
the multigrid preconditioner is told to keep its hierarchy. The operators agree with
PETSc's recomputed ones to round-off (``tests/linalg/test_galerkin.py``).

The same holds for any change of the fine operator: :func:`add_to_hierarchy` adds
P_lᵀ Δ P_l to each coarse operator for a change Δ, which costs little where Δ is
supported on few rows and columns (the nodes that join or leave the active set of
:mod:`admm_dolfinx.admm.polish_sparse`); :func:`sparse_difference` forms such a Δ.
"""

from __future__ import annotations

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

from admm_dolfinx.linalg.smoothers import set_up_smoother

__all__ = ["CoarsePenalty", "add_to_hierarchy", "sparse_difference"]


class CoarsePenalty:
    """Keeps a set-up GAMG preconditioner's coarse operators equal to P_lᵀ (A + rK) P_l.

    Args:
        pc: A ``PCGAMG`` set up on A + r K (its interpolation is kept from then on).
        penalty_matrix: K of that set-up (borrowed: its owner tells
            :meth:`change_matrix` before freeing it).
        r: r of that set-up.
    """

    def __init__(self, pc: PETSc.PC, penalty_matrix: PETSc.Mat, r: float):
        self.pc = pc
        self._matrix = penalty_matrix
        self._coefficient = float(r)
        self._projected: list[PETSc.Mat] = []  # K_l, coarsest first (fine level excluded)

    def change_matrix(self, penalty_matrix: PETSc.Mat) -> bool:
        """Penalise with another matrix from the next :meth:`move` on, if possible.

        Returns:
            Whether it is: only while the coarse operators hold no multiple of the
            present one (r = 0); otherwise the preconditioner must be set up afresh.
        """
        if self._coefficient != 0.0:
            return False
        self._free_projected()
        self._matrix = penalty_matrix
        return True

    def move(self, fine: PETSc.Mat, r: float) -> None:
        """Make the hierarchy that of ``fine`` = A + rK; collective.

        Args:
            fine: The fine operator, whose values the caller has set to A + rK (the
                same matrix object the preconditioner was set up with).
            r: The new r.
        """
        if not self._projected:
            self._project()
        pc, levels = self.pc, self.pc.getMGLevels()
        step = float(r) - self._coefficient
        for level in range(levels):
            smoother = pc.getMGSmoother(level)
            operator = fine if level == levels - 1 else smoother.getOperators()[0]
            if level < levels - 1 and step != 0.0:
                operator.axpy(
                    step,
                    self._projected[level],
                    structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN,
                )
            set_up_smoother(smoother, operator)
        self._coefficient = float(r)
        pc.setReusePreconditioner(True)  # the hierarchy is current: no PETSc set-up

    def _project(self) -> None:
        """K_l = P_lᵀ K P_l down the levels (each from the next finer one)."""
        pc, levels = self.pc, self.pc.getMGLevels()
        projected = [self._matrix]
        for level in range(levels - 1, 0, -1):
            projected.append(projected[-1].ptap(pc.getMGInterpolation(level)))
        self._projected = projected[:0:-1]  # coarsest first, the fine K dropped

    def _free_projected(self) -> None:
        for matrix in self._projected:
            matrix.destroy()
        self._projected = []

    def destroy(self) -> None:
        """Free the projected matrices (the preconditioner is its owner's)."""
        self._free_projected()


def add_to_hierarchy(pc: PETSc.PC, fine: PETSc.Mat, delta: PETSc.Mat) -> bool:
    """Make a kept multigrid hierarchy that of ``fine``, changed by ``delta``; collective.

    Each coarse operator gets P_lᵀ Δ P_l (each from the next finer one's), and the
    smoothers and the coarse solve are set up again on the new operators, as
    :meth:`CoarsePenalty.move` does for a change of r. The products' patterns lie
    within the coarse operators' (Δ's lies within the fine operator's, and PETSc's
    products keep every structural entry), so PETSc does not refuse a sum. Should it
    refuse one nonetheless, the refusal is agreed among the ranks (and the caller sets
    the preconditioner up afresh) where PETSc raises it on all of them alike; an error
    raised on one rank inside the sum's parallel assembly would not reach the others.

    Args:
        pc: A ``PCGAMG`` (``PCMG``) set up on ``fine`` − ``delta``, whose operators
            have not been changed since but by this function.
        fine: The fine operator, the same matrix object the preconditioner was set up
            with, its values already changed by ``delta``.
        delta: The change Δ of the fine operator (sparse: the products are cheap
            where few of its rows are non-empty).

    Returns:
        Whether the hierarchy is now ``fine``'s; if not, its coarse operators are
        spoiled and the caller sets the preconditioner up afresh.
    """
    comm = fine.getComm().tompi4py()
    levels = pc.getMGLevels()
    projected = delta
    try:
        for level in range(levels - 1, -1, -1):
            smoother = pc.getMGSmoother(level)
            if level == levels - 1:
                operator = fine
            else:
                coarser = projected.ptap(pc.getMGInterpolation(level + 1))
                if projected is not delta:
                    projected.destroy()
                projected = coarser
                operator = smoother.getOperators()[0]
                refused = False
                try:
                    operator.axpy(
                        1.0, projected, structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN
                    )
                except PETSc.Error:
                    refused = True
                if comm.allreduce(refused, op=MPI.LOR):
                    return False
            set_up_smoother(smoother, operator)
    finally:
        if projected is not delta:
            projected.destroy()
    pc.setReusePreconditioner(True)  # the hierarchy is current: no PETSc set-up
    return True


def sparse_difference(new: PETSc.Mat, old: PETSc.Mat) -> PETSc.Mat:
    """``new`` − ``old`` with only its nonzero entries stored; collective.

    Both must have the same parallel layout and the same sparsity pattern (a matrix
    and an earlier copy of it), so that the difference is taken entry by entry.

    Returns:
        Δ (the caller destroys it).

    Raises:
        ValueError: If the patterns differ (on any rank: raised on every rank).
    """
    rows, cols, values = new.getValuesCSR()
    rows_old, cols_old, values_old = old.getValuesCSR()
    same = np.array_equal(rows, rows_old) and np.array_equal(cols, cols_old)
    if not new.getComm().tompi4py().allreduce(same, op=MPI.LAND):
        raise ValueError("sparse_difference needs two matrices of the same pattern")
    change = values - values_old
    keep = change != 0.0
    n_rows = rows.size - 1
    row_of = np.repeat(np.arange(n_rows), np.diff(rows))
    indptr = np.zeros(rows.size, dtype=PETSc.IntType)
    np.cumsum(np.bincount(row_of[keep], minlength=n_rows), out=indptr[1:])
    delta = PETSc.Mat().createAIJ(
        new.getSizes(),
        csr=(indptr, cols[keep].astype(PETSc.IntType), change[keep]),
        comm=new.getComm(),
    )
    return delta
