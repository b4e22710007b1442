"""Is the contact zone resolved? An a-posteriori estimate of the peak pressure's error.

The solver returns the exact solution of the discrete problem; whether the mesh can
deliver the numbers an engineer reads is a separate question. A contact zone narrower
than a few elements is the usual failure: the pressure is then the mean over a
node's patch, far below the peak. After a solve, :func:`assess_resolution` looks at
the zone around the pressure peak:

* **The zone's half-width a, from the gaps.** Near the edge of a smooth (Hertzian)
  contact the remaining gap s(r) = g − N u opens in a known way: for a cylinder
  (2D) s/Δg = [ρ sqrt(ρ² − 1) − arccosh ρ] / ρ², for a sphere (3D)
  s/Δg = [ρ²/2 − 1 + ((2 − ρ²) arcsin(1/ρ) + sqrt(ρ² − 1))/π] / (ρ²/2), with ρ = r/a
  and Δg = g(r) − g(0) the initial gap's growth from the peak (Johnson, *Contact
  Mechanics*, 1985, §4.3 and §3.4). The ratio measured at the nearest free nodes
  gives ρ, hence a, with no material constant.
* **The peak pressure's error.** A contact node's pressure is the mean of the
  pressure over its patch (the lumped mass M_jj = ∫ φ_j ds). With the Hertzian profile
  p0 sqrt(1 − r²/a²) and a patch of radius r_M, the mean is p0 f(r_M/a) with f the
  profile's mean over the patch: the computed peak is f − 1 off. r_M comes from the
  patches of the nodes around the peak (a node on a symmetry plane has a part of one).
* **The obstacle between the nodes.** Where it enters the deformed contact facets
  at their centroids (a curved obstacle against coarse facets), by more than a
  fraction of the contact's length, the facets are too coarse for its curvature.

The zone is reported under-resolved when the peak's error is estimated above
:data:`PEAK_ERROR_LIMIT`, when a single node (in 2D) or at most three (in 3D) carry the
peak's zone, or when the obstacle enters the facets. The estimate assumes a smooth
contact (two curved surfaces, or a curved one on a plane); it is not made where the
gap does not grow away from the peak (conforming or flat contact, where the peak
sits at an edge of the zone and is no Hertzian one).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from dolfinx import mesh
from mpi4py import MPI

from admm_dolfinx._mpi import gather_concat
from admm_dolfinx.problem.contact_problem import ContactProblem
from admm_dolfinx.problem.contact_set import evaluate_obstacle, marked_facets
from admm_dolfinx.problem.kkt import contact_length

__all__ = [
    "PEAK_ERROR_LIMIT",
    "ContactResolution",
    "assess_resolution",
    "half_width_from_separation",
    "patch_mean",
]

#: A peak pressure estimated to be off by more than this is reported.
PEAK_ERROR_LIMIT = 0.05
#: The obstacle entering the deformed contact facets by more than this fraction of the
#: contact's length (:func:`~admm_dolfinx.problem.kkt.contact_length`) is reported.
BETWEEN_NODES_LIMIT = 0.05
#: The contact nodes nearest the peak that the assessment looks at.
_NEAREST = 48


def separation_ratio(rho: float, gdim: int) -> float:
    """Hertz's s(r)/Δg(r) outside a contact zone of half-width a, at ρ = r/a ≥ 1."""
    if rho <= 1.0:
        return 0.0
    if gdim == 2:
        return (rho * math.sqrt(rho * rho - 1.0) - math.acosh(rho)) / (rho * rho)
    inner = (2.0 - rho * rho) * math.asin(1.0 / rho) + math.sqrt(rho * rho - 1.0)
    return (rho * rho / 2.0 - 1.0 + inner / math.pi) / (rho * rho / 2.0)


def half_width_from_separation(distance: float, ratio: float, gdim: int) -> float | None:
    """The Hertzian half-width a for which s/Δg = ``ratio`` at ``distance`` from the peak.

    Args:
        distance: r, the free node's distance from the peak.
        ratio: The measured s/Δg there, in (0, 1).
        gdim: 2 (a cylinder's zone) or 3 (a sphere's).

    Returns:
        a, or None if the ratio is outside (0, 1) (no Hertzian zone fits it).
    """
    if not 0.0 < ratio < 1.0 or distance <= 0.0:
        return None
    lo, hi = 1.0, 2.0
    while separation_ratio(hi, gdim) < ratio:  # the ratio rises to 1 as ρ → ∞
        hi *= 2.0
        if hi > 1e8:
            return None
    for _ in range(80):  # bisection: the ratio is increasing in ρ
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if separation_ratio(mid, gdim) < ratio else (lo, mid)
    return distance / (0.5 * (lo + hi))


def patch_mean(t: float, gdim: int) -> float:
    """The mean of sqrt(1 − r²/a²)⁺ over a patch of radius t a (a segment in 2D, a disc in 3D)."""
    m = min(t, 1.0)
    if gdim == 2:
        return (math.asin(m) + m * math.sqrt(1.0 - m * m)) / (2.0 * t)
    if m >= 1.0:
        return 2.0 / (3.0 * t * t)
    return -2.0 / (3.0 * t * t) * math.expm1(1.5 * math.log1p(-m * m))  # no cancellation


@dataclass(frozen=True)
class ContactResolution:
    """How well the mesh resolves the contact zone around the pressure peak.

    Attributes:
        peak: The computed peak pressure max λ.
        where: The peak node's coordinates (None if nothing is in contact).
        active_near_peak: Contact nodes carrying pressure among those nearest the peak.
        half_width: The zone's half-width a estimated from the gaps at the nearest free
            nodes (None where no Hertzian zone fits).
        patch_radius: r_M, the radius of a contact node's patch near the peak.
        peak_error: The estimated relative error of the computed peak (negative: the
            computed peak is low), or None where it is not estimated.
        between_nodes: How deep the obstacle enters the deformed contact facets at their
            centroids (absolute; 0 if nowhere).
        between_where: That facet's centroid, or None.
        length: The contact's length ℓ that ``between_nodes`` is judged against.
        resolved: Whether the zone is resolved (no warning).
    """

    peak: float
    where: tuple[float, ...] | None
    active_near_peak: int
    half_width: float | None
    patch_radius: float
    peak_error: float | None
    between_nodes: float
    between_where: tuple[float, ...] | None
    length: float
    resolved: bool

    def message(self) -> str:
        """The warning for an under-resolved zone, with the estimate and the fix; "" if resolved."""
        if self.resolved:
            return ""
        text = "The contact zone is under-resolved."
        if self.where is not None:
            at = "(" + ", ".join(f"{x:.4g}" for x in self.where) + ")"
            text += (
                f" Around the pressure peak at {at}, {self.active_near_peak} contact node(s) "
                f"carry pressure, about {2.0 * self.patch_radius:.3g} apart"
            )
            if self.half_width is not None:
                text += (
                    "; the gaps at the nearest free nodes put the zone's half-width at about "
                    f"{self.half_width:.3g}"
                )
            text += "."
        if self.peak_error is not None:
            estimate = self.peak / (1.0 + self.peak_error)
            side = "below" if self.peak_error < 0 else "above"
            text += (
                f" The computed peak pressure {self.peak:.4g} is a mean over a node's patch: "
                f"about {abs(self.peak_error):.0%} {side} the peak of a Hertzian zone of that "
                f"width ({estimate:.4g})."
            )
        if self.between_where is not None:
            centroid = "(" + ", ".join(f"{x:.4g}" for x in self.between_where) + ")"
            text += (
                f" The obstacle enters the body between contact nodes by up to "
                f"{self.between_nodes:.3g} (at the facet centred at {centroid}): the facets "
                "there are too coarse for the obstacle's curvature."
            )
        size = (
            f" to about {self.half_width / 4:.3g} (a quarter of the half-width)"
            if self.half_width is not None
            else ""
        )
        return (
            f"{text} Refine the mesh near the contact{size}, or let "
            "admm_dolfinx.solve_adaptive refine it to a target error."
        )


def _nearest_to_peak(problem: ContactProblem, lam: npt.NDArray, slack: npt.NDArray):
    """The contact data of the nodes nearest the global peak, on every rank; collective."""
    c = problem.contact
    local_peak = float(np.max(lam, initial=0.0))
    peak = float(problem.comm.allreduce(local_peak, op=MPI.MAX))
    if peak <= 0.0:
        return peak, None
    # the peak node: the lowest coordinates among equal maxima (partition-independent)
    here = np.flatnonzero(lam == peak) if lam.size else np.zeros(0, dtype=int)
    candidates = problem.comm.allgather([tuple(c.coordinates[j]) for j in here])
    where = np.array(min(point for ranks in candidates for point in ranks))
    distance = np.linalg.norm(c.coordinates - where, axis=1)
    keep = np.argsort(distance, kind="stable")[:_NEAREST]
    columns = (
        distance[keep],
        lam[keep],
        slack[keep],
        c.gap[keep],
        c.mass[keep],
        c.coordinates[keep],
    )
    gathered = gather_concat(problem.comm, *columns)
    nearest = None
    if gathered is not None:
        order = np.lexsort((*gathered[5].T[::-1], gathered[0]))[:_NEAREST]
        nearest = tuple(column[order] for column in gathered)
    return peak, (where, problem.comm.bcast(nearest, root=0))


def _facets_entered(problem: ContactProblem, u) -> tuple[float, tuple[float, ...] | None]:
    """The deepest entry of the obstacle at the deformed contact facets' centroids; collective.

    Only in the default model (along the obstacle's normal); the paper's model measures
    the gap along the body's normal, which lets a curved body sink by construction.
    """
    if problem.contact.contact_normal != "obstacle":
        return 0.0, None
    msh = problem.mesh
    fdim, gdim = msh.topology.dim - 1, problem.gdim
    facets = marked_facets(problem.facet_tags, problem.contact_marker)
    facets = facets[facets < msh.topology.index_map(fdim).size_local]
    msh.topology.create_connectivity(fdim, msh.topology.dim)
    centroids = deformed = np.zeros((0, gdim))
    if facets.size:
        nodes = mesh.entities_to_geometry(msh, fdim, facets)
        centroids = msh.geometry.x[nodes].mean(axis=1)[:, :gdim]
        f2c = msh.topology.connectivity(fdim, msh.topology.dim)
        cells = f2c.array[f2c.offsets[facets]].astype(np.int32)  # an exterior facet's cell
        points = np.zeros((facets.size, 3))
        points[:, :gdim] = centroids
        deformed = centroids + u.eval(points, cells).reshape(facets.size, -1)[:, :gdim]
    gap, _ = evaluate_obstacle(
        problem.obstacle, deformed, np.zeros_like(deformed), problem.comm, "obstacle"
    )
    depth = np.where(np.isfinite(gap), np.maximum(-gap, 0.0), 0.0)
    deepest = float(problem.comm.allreduce(float(np.max(depth, initial=0.0)), op=MPI.MAX))
    if deepest <= 0.0:
        return 0.0, None
    mine = depth.size > 0 and float(np.max(depth)) == deepest
    found = gather_concat(
        problem.comm, centroids[[int(np.argmax(depth))]] if mine else np.zeros((0, gdim))
    )
    where = None if found is None else tuple(float(x) for x in found[0][0])
    return deepest, problem.comm.bcast(where, root=0)


def assess_resolution(problem: ContactProblem, u, multiplier) -> ContactResolution:
    """Judge whether the mesh resolves the contact zone of a solution; collective.

    Args:
        problem: The contact problem.
        u: The displacement Function (``result.u``).
        multiplier: λ at the owned contact nodes.

    Returns:
        The assessment (:meth:`ContactResolution.message` is the warning, if any).
    """
    gdim = problem.gdim
    lam = np.asarray(multiplier, dtype=np.float64)
    nu = problem.apply_normal(u.x.petsc_vec)
    c = problem.contact
    slack = np.where(np.isfinite(c.gap), c.gap - nu, np.inf)
    length = contact_length(problem, nu, lam)
    entered, entered_where = _facets_entered(problem, u)
    # judged against the contact's length; where no node touches at all, any entry of
    # the obstacle beyond round-off passes through the body between the nodes
    floor = 64 * np.finfo(np.float64).eps * problem.length_scale
    between = entered > max(BETWEEN_NODES_LIMIT * length, floor)
    peak, found = _nearest_to_peak(problem, lam, slack)
    if found is None:
        return ContactResolution(
            peak=peak,
            where=None,
            active_near_peak=0,
            half_width=None,
            patch_radius=0.0,
            peak_error=None,
            between_nodes=entered,
            between_where=entered_where if between else None,
            length=length,
            resolved=not between,
        )
    where, (distance, near_lam, near_slack, near_gap, near_mass, _) = found
    # a node's full patch: the median of the lumped masses near the peak (the peak's own
    # may be a part, cut by a symmetry plane)
    full_mass = float(np.median(near_mass[: 2 * gdim + 1]))
    patch = full_mass / 2.0 if gdim == 2 else math.sqrt(full_mass / math.pi)
    active = int(np.count_nonzero(near_lam[: 4 * gdim] > 0.0))
    free = np.flatnonzero((near_lam <= 0.0) & np.isfinite(near_gap))[: 2 if gdim == 2 else 6]
    widths = []
    for j in free:
        growth = near_gap[j] - near_gap[0]
        if growth > 0.0 and distance[j] > 0.0:
            a = half_width_from_separation(float(distance[j]), near_slack[j] / growth, gdim)
            if a is not None:
                widths.append(a)
    half_width = float(np.median(widths)) if widths else None
    peak_error = None
    if half_width is not None and half_width > 0.0:
        peak_error = patch_mean(patch / half_width, gdim) - 1.0
    few = active <= (1 if gdim == 2 else 3)
    coarse = peak_error is not None and abs(peak_error) > PEAK_ERROR_LIMIT
    resolved = not (coarse or between or (few and half_width is not None))
    return ContactResolution(
        peak=peak,
        where=tuple(float(x) for x in where),
        active_near_peak=active,
        half_width=half_width,
        patch_radius=patch,
        peak_error=peak_error,
        between_nodes=entered,
        between_where=entered_where if between else None,
        length=length,
        resolved=resolved,
    )
