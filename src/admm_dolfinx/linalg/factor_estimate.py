"""What a MUMPS factorisation of A would cost, from MUMPS's own analysis, before factorising.

The symbolic analysis (MUMPS ``JOB = 1``: ordering and elimination tree) is cheap
next to the numeric factorisation, and MUMPS reports from it the memory the
factorisation will need (``INFOG(16)``, ``INFOG(17)``: MB per process and in total,
in core) and its operation count (``RINFOG(1)``). The step-1 plan
(:mod:`admm_dolfinx.admm.plan`) uses them to choose between a factorisation and
multigrid.

petsc4py exposes the symbolic factorisation of a factor matrix as "not implemented",
so the analysis is called in PETSc's own library (``MatGetFactor`` and
``MatCholeskyFactorSymbolic`` through :mod:`ctypes`) on the handles petsc4py holds.
Where that library cannot be found, :func:`mumps_estimate` returns None and the plan
says so.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
from dataclasses import dataclass

from mpi4py import MPI
from petsc4py import PETSc

from admm_dolfinx.linalg.petsc import prefixed_options

__all__ = ["PARALLEL_ANALYSIS", "FactorEstimate", "available_memory", "mumps_estimate"]

#: PETSc's ``MAT_FACTOR_CHOLESKY`` (petscmat.h: NONE, LU, CHOLESKY, ...).
_MAT_FACTOR_CHOLESKY = 2


@dataclass(frozen=True)
class FactorEstimate:
    """MUMPS's estimates for a Cholesky factorisation.

    Attributes:
        memory: Bytes over all processes, in core (``INFOG(17)``).
        memory_per_process: The largest process's bytes (``INFOG(16)``).
        flops: Operations of the elimination (``RINFOG(1)``).
        factor_entries: Entries of the factors (``INFOG(20)``; negative: millions).
    """

    memory: float
    memory_per_process: float
    flops: float
    factor_entries: float


@functools.cache
def _library() -> ctypes.CDLL | None:
    """PETSc's shared library, as loaded in this process (None if not found)."""
    candidates = []
    try:
        with open("/proc/self/maps") as maps:
            candidates = sorted(
                {line.split()[-1] for line in maps if "libpetsc" in line and ".so" in line}
            )
    except OSError:  # not Linux
        pass
    found = ctypes.util.find_library("petsc")
    if found:
        candidates.append(found)
    for name in candidates:
        try:
            lib = ctypes.CDLL(name)
            lib.MatCholeskyFactorSymbolic  # noqa: B018 - raises if absent
            lib.MatMumpsGetInfog  # noqa: B018
        except (OSError, AttributeError):
            continue
        return lib
    return None


#: The analysis under MPI: MUMPS's parallel analysis with PT-SCOTCH's ordering
#: (ICNTL(28) = 2, ICNTL(29) = 1). The sequential analysis gathers the whole graph on
#: one rank and orders it there, so it takes as long on two ranks as on one; the
#: parallel one's ordering differs, and so do its estimates (the factorisation they
#: predict is one with the same analysis: ``tests/linalg/test_factor_estimate.py``).
#: A factorised step 1 keeps MUMPS's default (sequential) analysis: the plan's figures
#: are those of another ordering of the same matrix.
PARALLEL_ANALYSIS: dict[str, int] = {"mat_mumps_icntl_28": 2, "mat_mumps_icntl_29": 1}


def mumps_estimate(A: PETSc.Mat, *, prefix: str = "factor_estimate_") -> FactorEstimate | None:
    """MUMPS's analysis of a Cholesky factorisation of the SPD matrix A; collective.

    Under MPI the analysis is parallel (:data:`PARALLEL_ANALYSIS`, unless options
    under ``prefix`` choose the kind of analysis), and sequential if that fails (a
    MUMPS built without PT-SCOTCH). A failed analysis (MUMPS's ``INFOG(1) < 0``) gives
    None, never figures of zero.

    Args:
        A: The matrix (its values are not used: only its pattern is analysed).
        prefix: Options prefix of the analysis: ``-{prefix}mat_mumps_icntl_7 5``
            chooses its ordering, as for a factorisation.

    Returns:
        The estimates, or None if PETSc's library or MUMPS is not available, or the
        analysis failed.
    """
    lib = _library()
    if lib is None:
        return None
    comm = A.getComm().tompi4py()
    database = PETSc.Options()
    # the parallel analysis, unless the options under the prefix choose the kind of
    # analysis (ICNTL(28)) themselves: then theirs alone, once
    chosen = database.hasName(prefix + "mat_mumps_icntl_28")
    parallel = {k: v for k, v in PARALLEL_ANALYSIS.items() if not database.hasName(prefix + k)}
    attempts = [parallel, {}] if comm.size > 1 and not chosen else [{}]
    for options in attempts:
        with prefixed_options(prefix, options):
            estimate = _analyse(lib, A, prefix, comm)
        if estimate is not None:
            return estimate
    return None


def _analyse(lib: ctypes.CDLL, A: PETSc.Mat, prefix: str, comm) -> FactorEstimate | None:
    """One analysis with the options in the database under ``prefix``; collective."""
    voidp = ctypes.c_void_p
    lib.MatGetFactor.argtypes = [voidp, ctypes.c_char_p, ctypes.c_int, ctypes.POINTER(voidp)]
    lib.MatFactorInfoInitialize.argtypes = [voidp]
    lib.MatSetOptionsPrefix.argtypes = [voidp, ctypes.c_char_p]
    lib.MatCholeskyFactorSymbolic.argtypes = [voidp, voidp, voidp, voidp]
    int_type = ctypes.c_int64 if PETSc.IntType().itemsize == 8 else ctypes.c_int32
    lib.MatMumpsGetInfog.argtypes = [voidp, int_type, ctypes.POINTER(int_type)]
    lib.MatMumpsGetRinfog.argtypes = [voidp, int_type, ctypes.POINTER(ctypes.c_double)]
    lib.MatDestroy.argtypes = [ctypes.POINTER(voidp)]
    pattern = A.duplicate(copy=False)
    pattern.setOption(PETSc.Mat.Option.SPD, True)
    rows = PETSc.IS().createStride(A.getLocalSize()[0], A.getOwnershipRange()[0], 1, A.getComm())
    factor = voidp()
    info = (ctypes.c_double * 64)()  # MatFactorInfo: a few PetscReals, generously sized
    try:
        # a failure on any rank (no MUMPS in this PETSc, an error of the analysis) is
        # a failure on all, so that no rank waits in a collective call alone
        code = lib.MatGetFactor(voidp(pattern.handle), b"mumps", _MAT_FACTOR_CHOLESKY, factor)
        if comm.allreduce(bool(code), op=MPI.LOR):
            return None
        code = lib.MatSetOptionsPrefix(factor, prefix.encode())  # read by the analysis
        if comm.allreduce(bool(code), op=MPI.LOR):
            return None
        lib.MatFactorInfoInitialize(info)
        code = lib.MatCholeskyFactorSymbolic(
            factor, voidp(pattern.handle), voidp(rows.handle), info
        )
        if comm.allreduce(bool(code), op=MPI.LOR):
            return None
        values = {}
        for k in (1, 16, 17, 20):
            out = int_type()
            lib.MatMumpsGetInfog(factor, k, ctypes.byref(out))
            values[k] = float(out.value)
        flops = ctypes.c_double()
        lib.MatMumpsGetRinfog(factor, 1, ctypes.byref(flops))
    finally:
        if factor:
            lib.MatDestroy(ctypes.byref(factor))
        rows.destroy()
        pattern.destroy()
    # INFOG is global (the same on every rank); PETSc leaves an analysis error to the
    # numeric factorisation, which this never reaches
    if comm.allreduce(values[1] < 0, op=MPI.LOR):
        return None
    entries = values[20] if values[20] >= 0 else -values[20] * 1e6
    return FactorEstimate(
        memory=values[17] * 1e6,
        memory_per_process=values[16] * 1e6,
        flops=flops.value,
        factor_entries=entries,
    )


def available_memory() -> float | None:
    """Bytes of memory available on this machine (``MemAvailable``), or None if unknown."""
    try:
        with open("/proc/meminfo") as meminfo:
            for line in meminfo:
                if line.startswith("MemAvailable:"):
                    return float(line.split()[1]) * 1024.0
    except OSError:
        pass
    return None
