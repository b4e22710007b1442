"""The peak of the contact pressure, recovered from the noisy nodal values.

The nodal pressure λ_j = (contact force at node j) / M_jj of P1 elements with a lumped
contact mass is exact on average but scatters from node to node on unstructured
meshes: on the 3D Hertz sphere by a few percent of p0 that shrink only slowly with h
(``benchmarks/work_precision_adaptive.py`` prints the nodal and the recovered peak
side by side). Its maximum, max_j λ_j, takes the largest of that scatter and
converges erratically. One least-squares fit of a quadratic over the nodes nearest
the maximum (the nearest :data:`PEAK_SHARE` of the nodes in contact, at least
:data:`NEIGHBOURS`; patch recovery, Zienkiewicz & Zhu 1992), weighted by M_jj,
averages the scatter out; the recovered peak is the fitted quadratic's largest value
at those nodes. One smooth fit, not the largest of many, so the scatter does not
bias it upwards as the nodes multiply; it converges smoothly, which is what the
level-to-level estimate of :mod:`admm_dolfinx.adapt.quantities` needs.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from admm_dolfinx._mpi import RankLayout
from admm_dolfinx.problem.contact_problem import ContactProblem

__all__ = ["NEIGHBOURS", "PEAK_SHARE", "fitted_peak", "recovered_peak_pressure"]

#: The fewest nodes in contact the fit takes (and needs), by dimension of the body.
NEIGHBOURS = {2: 7, 3: 25}
#: The share of the nodes in contact, nearest the maximum, that the fit takes (a
#: Hertzian zone's peak region, where the pressure is close to a quadratic).
PEAK_SHARE = 0.1


def _basis(s: npt.NDArray) -> npt.NDArray:
    """The quadratic polynomials in the tangent coordinates s (k, 1 or 2)."""
    one = np.ones(len(s))
    if s.shape[1] == 1:
        return np.column_stack([one, s[:, 0], s[:, 0] ** 2])
    return np.column_stack([one, s[:, 0], s[:, 1], s[:, 0] ** 2, s[:, 0] * s[:, 1], s[:, 1] ** 2])


def fitted_peak(points: npt.NDArray, values: npt.NDArray, weights: npt.NDArray) -> float:
    """The largest value at ``points`` of the weighted least-squares quadratic through them.

    The quadratic is in coordinates of the points' own plane (their leading principal
    directions, about the first point); points that do not span it (in a line on a
    surface) fall back to the weighted mean.
    """
    offsets = points - points[0]
    _, sigma, vt = np.linalg.svd(offsets, full_matrices=False)
    dims = points.shape[1] - 1
    if sigma.size < dims or sigma[dims - 1] <= 1e-8 * max(sigma[0], 1e-300):
        return float(np.average(values, weights=weights))
    basis = _basis(offsets @ vt[:dims].T)
    root = np.sqrt(weights)
    coefficients, *_ = np.linalg.lstsq(basis * root[:, None], values * root, rcond=None)
    return float(np.max(basis @ coefficients))


def recovered_peak_pressure(problem: ContactProblem, multiplier: npt.ArrayLike) -> float:
    """The recovered peak of the contact pressure; collective, the same on every rank.

    Args:
        problem: The contact problem.
        multiplier: λ at the owned contact nodes.

    Returns:
        The largest patch-recovered pressure at the nodes near max λ; max λ itself where
        too few nodes are in contact for a fit (an under-resolved zone); 0 if none is.
    """
    c = problem.contact
    lam = np.asarray(multiplier, dtype=np.float64)
    active = lam > 0.0
    rows = np.vstack([c.coordinates[active].T, lam[active], c.mass[active]])
    layout = RankLayout(problem.comm, int(np.count_nonzero(active)))
    gathered = layout.gather(rows)
    peak, failure = 0.0, None
    if problem.comm.rank == 0:
        assert gathered is not None
        try:
            peak = _peak(gathered, problem.gdim)
        except Exception as error:  # e.g. a LinAlgError: every rank must hear of it
            failure = f"{type(error).__name__}: {error}"
    peak, failure = problem.comm.bcast((peak, failure), root=0)
    if failure is not None:
        raise RuntimeError(f"the recovery of the peak pressure failed on rank 0: {failure}")
    return float(peak)


def _peak(gathered: npt.NDArray, gdim: int) -> float:
    if gathered.shape[1] == 0:
        return 0.0
    x, lam, mass = gathered[:gdim].T, gathered[gdim], gathered[gdim + 1]
    order = np.lexsort(x.T[::-1])  # the same order whatever the partition
    x, lam, mass = x[order], lam[order], mass[order]
    if lam.size < NEIGHBOURS[gdim]:
        return float(lam.max())
    top = int(np.argmax(lam))
    count = max(NEIGHBOURS[gdim], int(PEAK_SHARE * lam.size))
    near = np.argsort(np.linalg.norm(x - x[top], axis=1), kind="stable")[:count]
    return fitted_peak(x[near], lam[near], mass[near])
