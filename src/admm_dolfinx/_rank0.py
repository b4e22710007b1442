"""Work that rank 0 does alone, with its failure raised on every rank.

Meshing (gmsh), files, figures and the dense contact algebra run on rank 0 only. If
such work raised there alone, the other ranks would wait forever at the next
collective call; :func:`run_on_rank0` broadcasts the outcome instead.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from mpi4py import MPI

__all__ = ["run_on_rank0"]


def run_on_rank0(
    comm: MPI.Comm, fn: Callable[[], Any], failure: Callable[[str, str, bool], Exception]
) -> Any:
    """``fn()`` on rank 0, its value broadcast; its failure raised on every rank.

    Args:
        comm: Communicator; collective.
        fn: The work, run on rank 0 only.
        failure: Builds the exception every rank raises from the failure's type name,
            its message and whether it is an ``OSError`` (on rank 0 it is chained to
            the original).

    Returns:
        ``fn()``'s value, on every rank.
    """
    value, error = None, None
    if comm.rank == 0:
        try:
            value = fn()
        except Exception as exc:
            error = exc
    report = comm.bcast(
        None if error is None else (type(error).__name__, str(error), isinstance(error, OSError)),
        root=0,
    )
    if report is not None:
        raise failure(*report) from error
    return comm.bcast(value, root=0)
