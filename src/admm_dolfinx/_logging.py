"""Logging that speaks on rank 0 of the communicator at work only.

Records are kept on rank 0 of the communicator of the problem being built or solved
(:func:`speaking_for`), and of ``COMM_WORLD`` outside such a block. So a problem on
``COMM_SELF`` of some rank of a parallel run logs there, and a problem on
``COMM_WORLD`` logs once.
"""

from __future__ import annotations

import contextlib
import contextvars
import logging
import warnings
from collections.abc import Iterator

from mpi4py import MPI

#: The communicator whose rank 0 speaks (None: ``COMM_WORLD``).
_SPEAKER: contextvars.ContextVar[MPI.Comm | None] = contextvars.ContextVar(
    "admm_dolfinx_speaker", default=None
)


def _speaks() -> bool:
    """Whether this process is rank 0 of the communicator at work."""
    comm = _SPEAKER.get()
    return (comm if comm is not None else MPI.COMM_WORLD).rank == 0


@contextlib.contextmanager
def speaking_for(comm: MPI.Comm) -> Iterator[None]:
    """Within the block, rank 0 of ``comm`` logs and warns (the others stay silent).

    Args:
        comm: The communicator of the problem being built or solved.
    """
    token = _SPEAKER.set(comm)
    try:
        yield
    finally:
        _SPEAKER.reset(token)


class _RankZeroFilter(logging.Filter):
    """Drop records emitted on any rank other than 0 of the communicator at work."""

    def filter(self, record: logging.LogRecord) -> bool:
        return _speaks()


def get_logger(name: str) -> logging.Logger:
    """Return ``logging.getLogger(name)`` with a filter that silences ranks > 0.

    Args:
        name: Logger name, normally ``__name__`` of the calling module.

    Returns:
        The configured logger.
    """
    logger = logging.getLogger(name)
    if not any(isinstance(f, _RankZeroFilter) for f in logger.filters):
        logger.addFilter(_RankZeroFilter())
    return logger


class ContactWarning(UserWarning):
    """A suspicious but solvable input (e.g. an obstacle no contact node can reach)."""


def warn(message: str, category: type[Warning] = ContactWarning) -> None:
    """Issue ``warnings.warn(message)`` on rank 0 of the communicator at work only."""
    if _speaks():
        warnings.warn(message, category, stacklevel=3)
