"""The peak of the contact pressure, recovered from the noisy nodal values.

The nodal pressure λ_j = (contact force at node j) / M_jj of P1 elements with a lumped
contact mass is exact on average but scatters from node to node on unstructured
meshes: on the 3D Hertz sphere by a few percent of p0 that shrink only slowly with h
(``benchmarks/work_precision_adaptive.py`` prints the nodal and the recovered peak
side by side). Its maximum, max_j λ_j, takes the largest of that scatter and
converges erratically. A least-squares fit of a quadratic over each node's nearest
contact neighbours (patch recovery, Zienkiewicz & Zhu 1992), weighted by M_jj,
averages the scatter out; the recovered peak is the largest fitted value at the
nodes near the maximum. It converges smoothly, which is what the level-to-level
estimate of :mod:`admm_dolfinx.adapt.quantities` needs.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from admm_dolfinx._mpi import RankLayout
from admm_dolfinx.problem.contact_problem import ContactProblem

__all__ = ["NEIGHBOURS", "recovered_peak_pressure"]

#: Nearest nodes in contact that each fit takes, by dimension of the body.
NEIGHBOURS = {2: 5, 3: 25}
#: Nodes whose λ is at least this share of max λ are candidates for the peak.
CANDIDATE_SHARE = 0.7


def _fit_at(points: npt.NDArray, values: npt.NDArray, weights: npt.NDArray) -> float:
    """The weighted least-squares quadratic through ``points`` (first = centre), at the centre."""
    offsets = points - points[0]
    # the contact surface's tangent plane at the centre: the leading directions
    _, _, vt = np.linalg.svd(offsets, full_matrices=False)
    dims = points.shape[1] - 1
    s = offsets @ vt[:dims].T
    if dims == 1:
        basis = np.column_stack([np.ones(len(s)), s[:, 0], s[:, 0] ** 2])
    else:
        basis = np.column_stack(
            [np.ones(len(s)), s[:, 0], s[:, 1], s[:, 0] ** 2, s[:, 0] * s[:, 1], s[:, 1] ** 2]
        )
    root = np.sqrt(weights)
    coefficients, *_ = np.linalg.lstsq(basis * root[:, None], values * root, rcond=None)
    return float(coefficients[0])


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
    peak = 0.0
    if problem.comm.rank == 0:
        assert gathered is not None
        peak = _peak(gathered, problem.gdim)
    return float(problem.comm.bcast(peak, root=0))


def _peak(gathered: npt.NDArray, gdim: int) -> float:
    if gathered.shape[1] == 0:
        return 0.0
    x, lam, mass = gathered[:gdim].T, gathered[gdim], gathered[gdim + 1]
    order = np.lexsort(x.T[::-1])  # the same order whatever the partition
    x, lam, mass = x[order], lam[order], mass[order]
    k = NEIGHBOURS[gdim]
    if lam.size < k:
        return float(lam.max())
    best = 0.0
    for j in np.flatnonzero(lam >= CANDIDATE_SHARE * lam.max()):
        distance = np.linalg.norm(x - x[j], axis=1)
        near = np.argsort(distance, kind="stable")[:k]  # j itself first
        best = max(best, _fit_at(x[near], lam[near], mass[near]))
    return best if best > 0.0 else float(lam.max())
