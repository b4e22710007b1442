"""The body's true surface near Γ_C, as the user gives it, and its checked, collective call.

A curved body's facets are chords of its surface; ``surface`` maps points to their
nearest points on it, so that refinement can place new vertices of Γ_C there
(:mod:`admm_dolfinx.adapt.refinement`) and the estimator can measure the obstacle's
entry at edge midpoints (:mod:`admm_dolfinx.adapt.estimator`).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import numpy.typing as npt

from admm_dolfinx._mpi import collective_call

__all__ = ["Surface", "project_on_surface"]

#: A map x (k, gdim) -> the nearest points of the body's true surface (k, gdim).
Surface = Callable[[npt.NDArray[np.float64]], npt.NDArray[np.float64]]


def project_on_surface(
    comm, surface: Surface, points: npt.NDArray[np.float64]
) -> npt.NDArray[np.float64]:
    """``surface(points)``, checked, on every rank (if it raises on one, on every one).

    Raises:
        ValueError: On every rank, if on any rank the map does not return finite points
            of the shape it was given.
    """

    def project() -> npt.NDArray[np.float64]:
        if not len(points):
            return np.zeros_like(points)
        moved = np.asarray(surface(points.copy()), dtype=np.float64)
        if moved.shape != points.shape or not np.all(np.isfinite(moved)):
            raise ValueError(
                "`surface` must map points of shape (k, gdim) to finite points of the "
                f"same shape; got shape {moved.shape} for {points.shape[0]} points."
            )
        return moved

    return collective_call(comm, project, "surface(x)")
