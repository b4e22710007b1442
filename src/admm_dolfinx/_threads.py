"""Threads of the dense linear algebra per MPI rank: no more threads than cores.

NumPy's OpenBLAS starts a thread per core in every process. Under ``mpiexec`` the ranks
that share a node then run more threads than the node has cores, and the small dense
products of the ADMM loop (the QR factorisations of Anderson acceleration, a few
columns of m-vectors) wait for descheduled threads, whose spinning takes the cores the
other ranks compute on. ``python benchmarks/scale_3d.py --mpi`` shows the iterations'
time outside step 1 under ``mpiexec`` against serial.

:func:`share_cores` gives each rank its share of the cores. The limit is process-wide
and stays after the solver is destroyed (NumPy code that runs later in the process
keeps it). A thread count the user chose (``OPENBLAS_NUM_THREADS``,
``OMP_NUM_THREADS``, ``MKL_NUM_THREADS``) is never overridden, and a pool's count is
only ever lowered.
"""

from __future__ import annotations

import os
from typing import Any

from mpi4py import MPI

from admm_dolfinx._logging import get_logger

__all__ = ["THREAD_VARIABLES", "cores_per_rank", "pools_above", "share_cores"]

logger = get_logger(__name__)

#: Environment variables through which a user fixes the BLAS thread count.
THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def _affinity() -> frozenset[int]:
    """The cores this process may run on (its affinity mask, where the OS has one)."""
    try:
        return frozenset(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - macOS, Windows
        return frozenset(range(os.cpu_count() or 1))


def cores_per_rank(node: MPI.Comm) -> int:
    """Each rank's share of the cores of its node; collective over ``node``.

    Ranks the launcher pinned to disjoint cores keep their own cores; ranks that may
    run on the same cores share them equally.

    Args:
        node: The ranks on one node (``MPI.COMM_TYPE_SHARED``).

    Returns:
        The number of threads this rank may run without oversubscribing the node.
    """
    mine = _affinity()
    masks = node.allgather(mine)
    if sum(len(mask) for mask in masks) == len(frozenset().union(*masks)):  # disjoint
        return len(mine)
    return max(1, len(frozenset().union(*masks)) // node.size)


def pools_above(info: list[dict[str, Any]], limit: int) -> dict[str, int]:
    """The BLAS pools of ``threadpool_info()`` with more than ``limit`` threads.

    Args:
        info: threadpoolctl's description of the loaded thread pools.
        limit: The most threads a pool may keep.

    Returns:
        ``{library path: limit}``, the limits to set (a pool with fewer keeps them).
    """
    return {
        pool["filepath"]: limit
        for pool in info
        if pool["user_api"] == "blas" and pool["num_threads"] > limit
    }


def share_cores(comm: MPI.Comm) -> int | None:
    """Limit each rank's BLAS threads to its share of the node's cores; collective.

    Args:
        comm: The communicator of the solve (collective over it); its ranks on one
            node (``MPI.COMM_TYPE_SHARED``) share that node's cores.

    Returns:
        The limit on this rank's BLAS threads, or None where none is set (one rank per
        node, a count the user chose, or no thread-pool control available).
    """
    node = comm.Split_type(MPI.COMM_TYPE_SHARED)
    try:
        ranks_on_node = node.size
        limit = cores_per_rank(node)
    finally:
        node.Free()
    if ranks_on_node == 1 or any(os.environ.get(name) for name in THREAD_VARIABLES):
        return None
    try:
        from threadpoolctl import threadpool_info, threadpool_limits
    except ImportError:  # pragma: no cover - a dependency of the package
        return None
    above = pools_above(threadpool_info(), limit)
    if above:
        threadpool_limits(limits=above)
        logger.debug(
            "%d ranks share this node: BLAS threads limited to %d per rank in %s",
            ranks_on_node,
            limit,
            ", ".join(sorted(above)),
        )
    return limit
