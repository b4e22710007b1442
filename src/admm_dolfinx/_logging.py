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
import os
import sys
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


#: ``ADMM_DOLFINX_PROGRESS=0`` turns off the progress lines of a long solve.
PROGRESS_VARIABLE = "ADMM_DOLFINX_PROGRESS"


def progress(logger: logging.Logger, message: str, *args: object) -> None:
    """A progress line of a long solve: logged at INFO, or shown in a terminal.

    Where the user has configured logging (a handler on the root logger, or a level on
    the package's logger), the line is an INFO record like any other. Where nothing
    is configured (a plain script), INFO records go nowhere; the line is then printed
    on stderr if it is a terminal, on rank 0 of the communicator at work, so that a
    long solve is not silent. ``ADMM_DOLFINX_PROGRESS=0``, or any level set on the
    ``admm_dolfinx`` logger, turns that off.
    """
    if logger.isEnabledFor(logging.INFO):
        logger.info(message, *args)
        return
    package = logging.getLogger("admm_dolfinx")
    configured = package.level != logging.NOTSET or bool(logging.getLogger().handlers)
    if configured or os.environ.get(PROGRESS_VARIABLE, "1") == "0" or not _speaks():
        return
    stream = sys.stderr
    if stream is not None and stream.isatty():
        print(message % args, file=stream, flush=True)
