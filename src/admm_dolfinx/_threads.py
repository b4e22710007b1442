"""Threads of the dense linear algebra per MPI rank: no more threads than cores.

NumPy's OpenBLAS starts a thread per core in every process. Under ``mpiexec`` the ranks
that share a node then run more threads than the node has cores, and the small dense
products of the ADMM loop (the QR factorisations of Anderson acceleration, a few
columns of m-vectors) wait for descheduled threads; the idle threads spin on the
cores the other ranks compute on. ``python benchmarks/scale_3d.py --mpi`` shows the
iterations' time outside step 1 at ``-n 2`` against serial.

:func:`share_cores` gives each rank its share of the cores it may run on. A thread
count the user chose (``OPENBLAS_NUM_THREADS``, ``OMP_NUM_THREADS``,
``MKL_NUM_THREADS``) is never overridden, and a count is only ever lowered.
"""

from __future__ import annotations

import os

from mpi4py import MPI

from admm_dolfinx._logging import get_logger

__all__ = ["THREAD_VARIABLES", "share_cores"]

logger = get_logger(__name__)

#: Environment variables through which a user fixes the BLAS thread count.
THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def _cores() -> int:
    """The cores this process may run on (its affinity mask, where the OS has one)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - macOS, Windows
        return os.cpu_count() or 1


def share_cores(comm: MPI.Comm) -> int | None:
    """Limit each rank's BLAS threads to its share of the node's cores; collective.

    The ranks of ``comm`` on one node (``MPI.COMM_TYPE_SHARED``) share the cores each
    may run on: a rank keeps at most ``max(1, cores // ranks on the node)`` threads.

    Args:
        comm: The communicator of the solve (collective over it).

    Returns:
        The limit on this rank's BLAS threads, or None where none is set (one rank per
        node, a count the user chose, or no thread-pool control available).
    """
    node = comm.Split_type(MPI.COMM_TYPE_SHARED)
    try:
        ranks_on_node = node.size
    finally:
        node.Free()
    if ranks_on_node == 1 or any(os.environ.get(name) for name in THREAD_VARIABLES):
        return None
    try:
        from threadpoolctl import threadpool_info, threadpool_limits
    except ImportError:  # pragma: no cover - a dependency of the package
        return None
    limit = max(1, _cores() // ranks_on_node)
    pools = [pool for pool in threadpool_info() if pool["user_api"] == "blas"]
    if all(pool["num_threads"] <= limit for pool in pools):
        return limit
    threadpool_limits(limits=limit, user_api="blas")
    logger.debug(
        "%d ranks share this node's %d cores: BLAS threads limited to %d per rank",
        ranks_on_node,
        _cores(),
        limit,
    )
    return limit
