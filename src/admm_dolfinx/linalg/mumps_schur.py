"""PETSc's calls on MUMPS factors that petsc4py does not wrap: the Schur complement.

The functions are resolved with ctypes in the PETSc library that petsc4py itself is
linked to (``dlsym`` on petsc4py's extension module searches its dependencies), so
they act on the same objects as petsc4py. Used by :mod:`admm_dolfinx.operators.condensed`, and
(selected entries of the inverse) by :mod:`admm_dolfinx.admm.polish_dense`.
"""

from __future__ import annotations

import ctypes

import numpy as np
import numpy.typing as npt
from petsc4py import PETSc

__all__ = [
    "CENTRALISED_RHS",
    "SchurBlock",
    "factorize_schur",
    "full_symmetric",
    "inverse_block",
    "selected_inverse_entries",
    "set_schur_indices",
]

_MAT_FACTOR_SCHUR_UNFACTORED = 0
_PETSC_INT = ctypes.c_int64 if np.dtype(PETSc.IntType).itemsize == 8 else ctypes.c_int32
_capi: ctypes.CDLL | None = None


def _petsc() -> ctypes.CDLL:
    global _capi
    if _capi is None:
        lib = ctypes.CDLL(PETSc.__file__)  # dlsym searches its dependencies: libpetsc
        vp, ip = ctypes.c_void_p, ctypes.c_int
        lib.MatFactorSetSchurIS.argtypes = [vp, vp]
        lib.MatFactorGetSchurComplement.argtypes = [vp, ctypes.POINTER(vp), ctypes.POINTER(ip)]
        lib.MatFactorRestoreSchurComplement.argtypes = [vp, ctypes.POINTER(vp), ip]
        lib.MatFactorFactorizeSchurComplement.argtypes = [vp]
        lib.MatDenseGetArray.argtypes = [vp, ctypes.POINTER(ctypes.POINTER(ctypes.c_double))]
        lib.MatDenseRestoreArray.argtypes = [vp, ctypes.POINTER(ctypes.POINTER(ctypes.c_double))]
        lib.MatGetSize.argtypes = [vp, ctypes.POINTER(_PETSC_INT), ctypes.POINTER(_PETSC_INT)]
        lib.MatMumpsGetInverseTranspose.argtypes = [vp, vp]
        _capi = lib
    return _capi


def _call(name: str, *args) -> None:
    code = getattr(_petsc(), name)(*args)
    if code != 0:
        raise RuntimeError(f"PETSc {name} failed with error code {code}.")


def full_symmetric(block: npt.NDArray[np.float64], serial: bool) -> npt.NDArray[np.float64]:
    """The symmetric S_C from the triangle of ``block`` that MUMPS filled.

    ``block`` is the Schur buffer read column by column. For a symmetric factorisation
    MUMPS fills one triangle only: the lower one on one process, the lower one by rows
    (the upper one read by columns) when the factorisation is distributed. The other
    triangle is not zeroed and may hold scratch values (seen under MPI), so it is never
    read.
    """
    half = np.tril(block) if serial else np.triu(block)
    return half + np.tril(half, -1).T if serial else half + np.triu(half, 1).T


class SchurBlock:
    """The factored matrix's dense Schur block (MUMPS's storage), overwritten in place."""

    def __init__(self, factor: PETSc.Mat):
        self.factor = factor

    def __enter__(self) -> npt.NDArray[np.float64]:
        self._mat = ctypes.c_void_p()
        status = ctypes.c_int()
        _call("MatFactorGetSchurComplement", self.factor.handle, self._mat, status)
        rows, cols = _PETSC_INT(), _PETSC_INT()
        _call("MatGetSize", self._mat, rows, cols)
        self._array = ctypes.POINTER(ctypes.c_double)()
        _call("MatDenseGetArray", self._mat, self._array)
        # column-major storage; S is symmetric, the caller writes whole matrices
        return np.ctypeslib.as_array(self._array, shape=(cols.value, rows.value))

    def __exit__(self, *exc) -> None:
        _call("MatDenseRestoreArray", self._mat, self._array)
        _call(
            "MatFactorRestoreSchurComplement",
            self.factor.handle,
            self._mat,
            _MAT_FACTOR_SCHUR_UNFACTORED,
        )


def set_schur_indices(factor: PETSc.Mat, indices: PETSc.IS) -> None:
    """``MatFactorSetSchurIS``: keep ``indices`` back as a dense Schur complement."""
    _call("MatFactorSetSchurIS", factor.handle, indices.handle)


def factorize_schur(factor: PETSc.Mat) -> None:
    """``MatFactorFactorizeSchurComplement``: factorise the (modified) dense block now."""
    _call("MatFactorFactorizeSchurComplement", factor.handle)


def selected_inverse_entries(factor: PETSc.Mat, pattern: PETSc.Mat) -> None:
    """``MatMumpsGetInverseTranspose``: fill ``pattern`` with those entries of A⁻ᵀ.

    MUMPS's selected entries of the inverse (ICNTL(30)) from existing factors. The
    right-hand side is centralised: ``pattern`` is an AIJ matrix of A's size whose rows
    all live on rank 0 (a sequential one on one process). Under MPI the factorisation
    must have been made with a centralised dense right-hand side
    (``mat_mumps_icntl_20 = 0``: MUMPS refuses a sparse one next to the distributed
    one's arrays). The factors are left ready for ordinary solves again (the
    right-hand side and solution formats, ICNTL(20) and ICNTL(21), restored).
    """
    rhs, solution = factor.getMumpsIcntl(20), factor.getMumpsIcntl(21)
    try:
        _call("MatMumpsGetInverseTranspose", factor.handle, pattern.handle)
    finally:
        factor.setMumpsIcntl(30, 0)
        factor.setMumpsIcntl(20, rhs)
        factor.setMumpsIcntl(21, solution)


#: The step-1 options under which :func:`inverse_block` works on several processes.
CENTRALISED_RHS = {"mat_mumps_icntl_20": 0}


def inverse_block(
    factor: PETSc.Mat, dofs: npt.NDArray[np.integer]
) -> npt.NDArray[np.float64] | None:
    """The dense block (A⁻¹)_CC, C = ``dofs``, from MUMPS factors of a symmetric A.

    MUMPS's selected entries of the inverse (:func:`selected_inverse_entries`): the
    factors are reused, no other factorisation is made. Collective: the requested
    pattern lives on rank 0, and so does the block; under MPI the factorisation must
    have been made with :data:`CENTRALISED_RHS`. Memory on rank 0: the pattern and the
    dense block, about 24 c² bytes for c = |C|.

    Args:
        factor: The factor matrix of a MUMPS Cholesky (or LU) factorisation of A.
        dofs: The global indices of C, sorted (on rank 0; ignored elsewhere).

    Returns:
        The c × c block, symmetrised (the two triangles agree to round-off), on rank 0;
        None elsewhere.
    """
    comm = factor.getComm()
    n = factor.getSize()[0]
    host = comm.getRank() == 0
    rows = n if host else 0
    c = int(dofs.size) if host else 0
    counts = np.zeros(rows, dtype=PETSc.IntType)
    if host:
        counts[dofs] = c
    indptr = np.concatenate([[0], np.cumsum(counts)]).astype(PETSc.IntType)
    columns = np.tile(np.asarray(dofs if host else [], dtype=PETSc.IntType), c)
    pattern = PETSc.Mat().createAIJ(
        ((rows, n), (rows, n)), csr=(indptr, columns, np.zeros(c * c)), comm=comm
    )
    try:
        selected_inverse_entries(factor, pattern)
        # rows of C in order, each with C's columns sorted
        block = pattern.getValuesCSR()[2].reshape(c, c) if host else None
    finally:
        pattern.destroy()
    return 0.5 * (block + block.T) if block is not None else None
