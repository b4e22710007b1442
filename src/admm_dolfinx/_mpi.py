"""The one home of the package's MPI patterns: rank-0 work, gathers, and shared failures.

Two rules keep a distributed run from hanging:

* **Rank-0 work.** Dense algebra, files and figures run on rank 0 alone. If that work
  raised there only, the other ranks would wait forever at the next collective call:
  :func:`run_on_rank0` broadcasts the outcome, and every rank raises.
* **User code.** An obstacle's gap, a callback or a user's data may fail (or answer
  differently) on one rank only: :func:`collective_call` runs such code on every rank
  and raises on every rank if it raised on any, whatever it raised:
  ``KeyboardInterrupt`` and ``SystemExit`` included (the rank that raised one re-raises
  its own; the others raise a ``RuntimeError`` that names it). mpi4py's
  abort-on-exception does not help here: with petsc4py initialised it does not fire.

Distributed nodal arrays (one value per owned contact node) are collected on rank 0 in
rank order and split back with :class:`RankLayout`, which handles ranks that own no
node at all.
"""

from __future__ import annotations

import builtins
from collections.abc import Callable
from typing import Any, TypeVar

import numpy as np
import numpy.typing as npt
from mpi4py import MPI

__all__ = [
    "OnRank0",
    "RankLayout",
    "agree",
    "check_same_on_every_rank",
    "collective_call",
    "from_rank0",
    "gather_concat",
    "gather_csr",
    "gather_objects",
    "probe_vector",
    "raise_collectively",
    "rebuilt_exception",
    "run_on_rank0",
]

T = TypeVar("T")


def probe_vector(coords: npt.NDArray[np.floating], seed: float = 0.5) -> npt.NDArray[np.float64]:
    """Pseudo-random values in (−½, ½) that depend only on point coordinates.

    A Krylov sequence (or a check) started from them gives the same result on any
    partition of the mesh.

    Args:
        coords: Points, shape (k, d) with d ≤ 3.
        seed: Varies the values (0.5 is the package's usual start).
    """
    x = np.zeros((coords.shape[0], 3))
    x[:, : coords.shape[1]] = coords
    phase = np.sin(x @ np.array([12.9898, 78.233, 37.719]) + seed) * 43758.5453
    return phase - np.floor(phase) - 0.5


def rebuilt_exception(name: str, text: str) -> Exception:
    """An exception of the builtin type ``name`` (RuntimeError if it is not one)."""
    kind = getattr(builtins, name, None)
    if isinstance(kind, type) and issubclass(kind, Exception) and kind is not BaseException:
        try:
            return kind(text)
        except Exception:  # pragma: no cover - exotic constructor signatures
            pass
    return RuntimeError(f"{name}: {text}")


def raise_collectively(comm: MPI.Comm, error: BaseException | None, what: str) -> None:
    """Raise on every rank if ``error`` is set on any; collective.

    The lowest failing rank's error is raised: on that rank the original (unchanged),
    on the others an exception of the same builtin type whose message says where it
    happened (a ``RuntimeError`` for a type that is not an ``Exception``). A rank whose
    own error is a ``KeyboardInterrupt`` or ``SystemExit`` re-raises it whatever the
    other ranks raised: an interrupt is never turned into an ordinary error.

    Args:
        comm: Communicator.
        error: This rank's exception, or None.
        what: What was being done, for the message on the other ranks.
    """
    report = None if error is None else (type(error).__name__, str(error))
    reports = comm.allgather(report)
    failed = [(rank, rep) for rank, rep in enumerate(reports) if rep is not None]
    if not failed:
        return
    rank, (name, text) = failed[0]
    if error is not None and (comm.rank == rank or not isinstance(error, Exception)):
        raise error
    raise rebuilt_exception(name, f"{what} failed on rank {rank}: {text}") from error


def collective_call(comm: MPI.Comm, fn: Callable[[], T], what: str) -> T:
    """``fn()`` on every rank; if it raises on any rank, raise on every rank; collective.

    Args:
        comm: Communicator.
        fn: The work (typically user code), run on every rank.
        what: What ``fn`` is, for the message (``"Plane.gap"``).

    Returns:
        ``fn()``'s value on this rank.
    """
    value, error = None, None
    try:
        value = fn()
    except BaseException as exc:  # KeyboardInterrupt, SystemExit too: every rank leaves
        error = exc
    raise_collectively(comm, error, what)
    return value  # type: ignore[return-value]


def check_same_on_every_rank(comm: MPI.Comm, values: dict[str, Any], what: str) -> None:
    """Raise on every rank if some of ``values`` differ between the ranks; collective.

    A setting computed per rank (``rtol=1e-6 * 10**-rank``, a penalty read from a
    per-rank file) would make the ranks take different branches of a collective
    algorithm: a hang, or an answer that depends on the rank. Values are compared by
    their ``repr``.

    Args:
        comm: Communicator.
        values: The settings by name.
        what: Whose settings they are (``"The solver's settings"``), for the message.

    Raises:
        ValueError: On every rank alike, naming each setting that differs and its
            values on the first ranks.
    """
    mine = {name: repr(value) for name, value in sorted(values.items())}
    everyone = comm.allgather(mine)
    differ = [name for name in mine if any(other.get(name) != mine[name] for other in everyone)]
    if not differ:
        return
    shown = "; ".join(
        f"{name}: "
        + ", ".join(
            f"{everyone[rank].get(name)} on rank {rank}" for rank in range(min(3, comm.size))
        )
        for name in differ
    )
    raise ValueError(
        f"{what} differ between the MPI ranks ({shown}). Every rank must pass the same "
        "values: compute them on one rank and broadcast them (comm.bcast(value, root=0))."
    )


def agree(comm: MPI.Comm, flag: bool) -> tuple[bool, bool]:
    """(any rank True, all ranks agree) for a flag that user code computed per rank."""
    flags = comm.allgather(bool(flag))
    return any(flags), all(f == flags[0] for f in flags)


def from_rank0(comm: MPI.Comm, value: T) -> T:
    """A (small) value that rank 0 computed, on every rank; collective.

    Rank 0's work itself must not raise there alone: run it with :func:`run_on_rank0`,
    or catch its failures into the value.
    """
    return comm.bcast(value, root=0)


class OnRank0:
    """A ``with`` block whose work runs on rank 0 alone, its failure raised on every rank.

    Usage (collective; the work is written inline, no callback)::

        with OnRank0(comm, failure) as work:
            if work.here:
                work.value = compute()
        value = work.value  # on every rank (on rank 0 only if broadcast is False)

    On leaving the block, rank 0 tells every rank whether its work raised; if it did,
    every rank raises ``failure(type name, message, is OSError)`` (on rank 0 chained
    to the original; a ``KeyboardInterrupt`` or ``SystemExit`` there is re-raised as
    itself); otherwise the value is broadcast.

    Args:
        comm: Communicator.
        failure: Builds the exception every rank raises.
        broadcast: Broadcast the value; if False it stays on rank 0 (None elsewhere),
            e.g. for an array that is scattered next.
    """

    def __init__(
        self,
        comm: MPI.Comm,
        failure: Callable[[str, str, bool], Exception],
        *,
        broadcast: bool = True,
    ):
        self.comm = comm
        self.failure = failure
        self.broadcast = broadcast
        self.here = comm.rank == 0
        self.value: Any = None

    def __enter__(self) -> OnRank0:
        return self

    def __exit__(self, kind, error, traceback) -> None:
        report = None
        if self.here and error is not None:
            report = (type(error).__name__, str(error), isinstance(error, OSError))
        report = self.comm.bcast(report, root=0)
        if report is not None:
            if error is not None and not isinstance(error, Exception):
                return  # rank 0's KeyboardInterrupt, SystemExit: propagates as itself
            raise self.failure(*report) from error
        if error is not None:  # raised on another rank than 0: it propagates there
            return
        if self.broadcast:
            self.value = self.comm.bcast(self.value, root=0)


def run_on_rank0(
    comm: MPI.Comm,
    fn: Callable[[], Any],
    failure: Callable[[str, str, bool], Exception],
    *,
    broadcast: bool = True,
) -> Any:
    """``fn()`` on rank 0, its value broadcast; its failure raised on every rank.

    The callback form of :class:`OnRank0`.

    Args:
        comm: Communicator; collective.
        fn: The work, run on rank 0 only.
        failure: Builds the exception every rank raises from the failure's type name,
            its message and whether it is an ``OSError`` (on rank 0 it is chained to
            the original).
        broadcast: Broadcast the value; if False it stays on rank 0 (None elsewhere),
            e.g. for an array that is scattered next.

    Returns:
        ``fn()``'s value, on every rank (on rank 0 only if ``broadcast`` is False).
    """
    with OnRank0(comm, failure, broadcast=broadcast) as work:
        if work.here:
            work.value = fn()
    return work.value


class RankLayout:
    """How a distributed array of per-node values lies over the ranks (rank order).

    Args:
        comm: Communicator.
        local_size: Number of values this rank owns (may be 0).

    Attributes:
        counts: Values per rank, on every rank.
        offsets: Start of each rank's block in the gathered array (length size + 1).
        total: Global number of values.
    """

    def __init__(self, comm: MPI.Comm, local_size: int):
        self.comm = comm
        self.counts = np.array(comm.allgather(int(local_size)), dtype=np.int64)
        self.offsets = np.concatenate([[0], np.cumsum(self.counts)]).astype(np.int64)
        self.total = int(self.offsets[-1])

    @property
    def local_size(self) -> int:
        """Number of values on this rank."""
        return int(self.counts[self.comm.rank])

    @property
    def start(self) -> int:
        """Offset of this rank's block in the gathered array."""
        return int(self.offsets[self.comm.rank])

    def gather(self, rows: npt.ArrayLike) -> npt.NDArray[np.float64] | None:
        """Stack (k, n_loc) blocks (or (n_loc,) vectors) into (k, n) on rank 0; collective.

        Returns:
            The gathered array on rank 0, None on the other ranks.
        """
        local = np.asarray(rows, dtype=np.float64)
        vector = local.ndim == 1
        block = np.ascontiguousarray(local.reshape(1, -1) if vector else local)
        k = block.shape[0]
        if k == 0:
            return np.zeros((0, self.total)) if self.comm.rank == 0 else None
        if block.shape[1] != self.local_size:
            raise ValueError(  # pragma: no cover - internal misuse
                f"internal: {block.shape[1]} values on rank {self.comm.rank}, layout has "
                f"{self.local_size}"
            )
        if self.comm.size == 1:
            out = block.copy()
            return out[0] if vector else out
        # column blocks per rank: send rank-major (k, n_loc) as one contiguous piece
        sizes = self.counts * k
        recv = np.empty(int(sizes.sum())) if self.comm.rank == 0 else None
        self.comm.Gatherv(block.ravel(), [recv, sizes] if recv is not None else None, root=0)
        if recv is None:
            return None
        pieces = np.split(recv, np.cumsum(sizes)[:-1])
        out = np.hstack([p.reshape(k, -1) for p in pieces])
        return out[0] if vector else out

    def scatter(self, rows: npt.ArrayLike | None, k: int | None = None) -> npt.NDArray[np.float64]:
        """Split (k, n) (or (n,)) on rank 0 into each rank's (k, n_loc); collective.

        Args:
            rows: The array on rank 0 (ignored elsewhere).
            k: Rows per rank; ``None`` for a vector (then every rank gets (n_loc,)).

        Returns:
            This rank's block.
        """
        vector = k is None
        rows_k = 1 if k is None else int(k)
        if self.comm.size == 1:
            full = np.asarray(rows, dtype=np.float64)
            return full.copy() if vector else full.reshape(rows_k, -1).copy()
        send = None
        if self.comm.rank == 0:
            full = np.asarray(rows, dtype=np.float64).reshape(rows_k, -1)
            bounds = zip(self.offsets[:-1], self.offsets[1:], strict=True)
            send = np.concatenate([full[:, a:b].ravel() for a, b in bounds])
        recv = np.empty(rows_k * self.local_size)
        self.comm.Scatterv([send, self.counts * rows_k] if send is not None else None, recv, root=0)
        return recv if vector else recv.reshape(rows_k, self.local_size)

    def allgather(self, values: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """The whole (n,) or (n, d) array on every rank, in rank order; collective."""
        local = np.asarray(values, dtype=np.float64)
        parts = self.comm.allgather(local)
        return np.concatenate(parts, axis=0)


def gather_objects(comm: MPI.Comm, item: T) -> list[T] | None:
    """Every rank's ``item`` in a list on rank 0 (None elsewhere); collective."""
    return comm.gather(item, root=0)


def gather_concat(comm: MPI.Comm, *arrays: npt.ArrayLike) -> tuple[npt.NDArray, ...] | None:
    """Each array concatenated over the ranks (rank order) on rank 0; collective.

    Arrays of any length (ranks with none send empty ones), along their first axis.

    Returns:
        The concatenated arrays on rank 0, None elsewhere.
    """
    pieces = comm.gather(tuple(np.asarray(a) for a in arrays), root=0)
    if pieces is None:
        return None
    return tuple(np.concatenate([p[i] for p in pieces], axis=0) for i in range(len(arrays)))


def gather_csr(
    comm: MPI.Comm,
    csr: tuple[npt.NDArray, npt.NDArray, npt.NDArray],
) -> tuple[npt.NDArray, npt.NDArray, npt.NDArray] | None:
    """Stack each rank's CSR rows (rank order) into one CSR matrix on rank 0; collective.

    Column indices are left as they are (global), so the blocks must already use one
    column numbering. A rank without rows sends ``indptr = [0]``.

    Returns:
        ``(indptr, indices, data)`` on rank 0, None elsewhere.
    """
    pieces = comm.gather(tuple(np.asarray(a) for a in csr), root=0)
    if pieces is None:
        return None
    indptr = [np.zeros(1, dtype=np.int64)]
    offset = 0
    for ip, _, _ in pieces:
        ip = np.asarray(ip, dtype=np.int64)
        indptr.append(ip[1:] - ip[0] + offset)
        offset += int(ip[-1] - ip[0]) if ip.size else 0
    indices = np.concatenate([np.asarray(p[1], dtype=np.int64) for p in pieces])
    data = np.concatenate([np.asarray(p[2], dtype=np.float64) for p in pieces])
    return np.concatenate(indptr), indices, data
