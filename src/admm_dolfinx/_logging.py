"""Logging that speaks on MPI rank 0 only."""

from __future__ import annotations

import logging
import warnings

from mpi4py import MPI


class _RankZeroFilter(logging.Filter):
    """Drop records emitted on any rank other than 0 of ``COMM_WORLD``."""

    def filter(self, record: logging.LogRecord) -> bool:
        return MPI.COMM_WORLD.rank == 0


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
    """Issue ``warnings.warn(message)`` on rank 0 of ``COMM_WORLD`` only (once per rank set)."""
    if MPI.COMM_WORLD.rank == 0:
        warnings.warn(message, category, stacklevel=3)
