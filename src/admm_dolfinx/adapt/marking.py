"""Which edges to split: Dörfler's bulk criterion, and the contact zone.

* **Dörfler marking** (Dörfler 1996): the fewest edges with the largest indicators
  whose sum is at least θ of the total, found as a threshold t (every edge with
  η_e² ≥ t is marked) by bisection on global sums, so that every partition marks
  the same edges. The indicators are rounded to :data:`SIGNIFICANT` digits first:
  edges whose indicators differ by round-off (the many equal ones of a symmetric
  mesh) are then marked alike on any partition.
* **The contact zone**, split at every level: the edges of Γ_C near the nodes in
  contact (the active ones and their neighbours). The element size of the zone then
  halves from one level to the next, which is what the estimate of a quantity's
  error from successive levels needs (:mod:`admm_dolfinx.adapt.quantities`).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from dolfinx import fem, la, mesh
from mpi4py import MPI

from admm_dolfinx.adapt.estimator import EdgeIndicators
from admm_dolfinx.adapt.shared_vertices import agreed_vertex_flags
from admm_dolfinx.problem.contact_problem import ContactProblem
from admm_dolfinx.problem.contact_set import marked_facets

__all__ = ["SIGNIFICANT", "contact_zone_edges", "count_edges", "doerfler_edges", "graded_edges"]

#: Significant digits the indicators keep before the threshold is sought.
SIGNIFICANT = 8


def _rounded(values: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    out = np.zeros_like(values)
    positive = values > 0.0
    exponent = np.floor(np.log10(values[positive]))
    scale = 10.0 ** (SIGNIFICANT - 1 - exponent)
    out[positive] = np.round(values[positive] * scale) / scale
    return out


def doerfler_edges(
    indicators: EdgeIndicators, theta: float, comm: MPI.Comm
) -> npt.NDArray[np.int32]:
    """The local edges of Dörfler's set for the bulk fraction θ; collective.

    Args:
        indicators: η_e² per local edge.
        theta: The fraction θ ∈ (0, 1] of Σ η_e² the marked edges carry.
        comm: The mesh's communicator.

    Returns:
        The marked local edges (owned ones; the refinement shares them).
    """
    eta = np.where(indicators.owned, _rounded(indicators.values), 0.0)
    total = float(comm.allreduce(float(eta.sum()), op=MPI.SUM))
    if total <= 0.0:
        return np.zeros(0, dtype=np.int32)
    top = float(comm.allreduce(float(eta.max(initial=0.0)), op=MPI.MAX))
    lo, hi = 0.0, top  # Σ_{η ≥ lo} ≥ θ total; Σ_{η ≥ hi} may be short of it
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        carried = float(comm.allreduce(float(eta[eta >= mid].sum()), op=MPI.SUM))
        lo, hi = (mid, hi) if carried >= theta * total else (lo, mid)
        if hi - lo <= 1e-12 * top:
            break
    # the threshold is an indicator's own value: the smallest one not below lo (the
    # set {η ≥ lo} carries θ of the total; no larger threshold does)
    candidates = eta[eta >= lo]
    threshold = float(comm.allreduce(float(candidates.min(initial=np.inf)), op=MPI.MIN))
    return np.flatnonzero(eta >= threshold).astype(np.int32)


def contact_zone_edges(
    problem: ContactProblem, multiplier: npt.NDArray[np.float64]
) -> npt.NDArray[np.int32]:
    """The local edges of the cells at the contact zone (its nodes and their neighbours).

    Where nothing is in contact, the zone is all of Γ_C that the obstacle can reach.

    Args:
        problem: The contact problem.
        multiplier: λ at the owned contact nodes.

    Returns:
        Local edge indices (empty if nothing is in contact).
    """
    msh = problem.mesh
    fdim = msh.topology.dim - 1
    Q = problem.contact.Q
    active = np.zeros(Q.dofmap.index_map.size_local + Q.dofmap.index_map.num_ghosts)
    active[problem.contact.dofs] = np.asarray(multiplier) > 0.0
    carrier = fem.Function(Q)
    carrier.x.array[:] = active
    carrier.x.scatter_forward()
    vertex_active = carrier.x.array[_vertex_to_q(problem)] > 0.5
    if not msh.comm.allreduce(bool(np.any(active)), op=MPI.LOR):
        # nothing touches on this mesh (the contact may fall between its nodes): the
        # whole of Γ_C where the obstacle can reach (a finite gap) is the zone
        reach = np.zeros_like(active)
        reach[problem.contact.dofs] = np.isfinite(problem.contact.gap)
        carrier.x.array[:] = reach
        carrier.x.scatter_forward()
        vertex_active = carrier.x.array[_vertex_to_q(problem)] > 0.5
    facets = marked_facets(problem.facet_tags, problem.contact_marker)
    msh.topology.create_connectivity(fdim, 0)
    f2v = msh.topology.connectivity(fdim, 0)
    per_facet = msh.topology.dim  # a simplex's facet has tdim vertices (any rank, empty too)
    facet_vertices = f2v.array.reshape(-1, per_facet)[facets]
    touching = facets[np.any(vertex_active[facet_vertices], axis=1)]
    # and one ring further along Γ_C: the vertices of those facets, agreed on by every
    # rank that holds them (a rank may hold one through a cell without the facet)
    ring_vertices = agreed_vertex_flags(msh, f2v.array.reshape(-1, per_facet)[touching].ravel())
    # every edge of the cells that touch the zone: the cells are split whole, so that the
    # zone's elements stay shaped as they were (splitting Γ_C's edges alone would
    # leave slivers under it)
    tdim = msh.topology.dim
    msh.topology.create_connectivity(tdim, 0)
    msh.topology.create_connectivity(tdim, 1)
    c2v = msh.topology.connectivity(tdim, 0)
    c2e = msh.topology.connectivity(tdim, 1)
    n_cells = msh.topology.index_map(tdim).size_local + msh.topology.index_map(tdim).num_ghosts
    if not n_cells:
        return np.zeros(0, dtype=np.int32)
    cell_vertices = c2v.array.reshape(n_cells, -1)
    cells = np.flatnonzero(np.any(ring_vertices[cell_vertices], axis=1))
    return np.unique(c2e.array.reshape(n_cells, -1)[cells]).astype(np.int32)


def _vertex_to_q(problem: ContactProblem) -> npt.NDArray[np.int32]:
    """The scalar contact space's dof at every local vertex."""
    msh = problem.mesh
    tdim = msh.topology.dim
    msh.topology.create_connectivity(tdim, 0)
    c2v = msh.topology.connectivity(tdim, 0)
    dofs = problem.contact.Q.dofmap.list
    n_vertices = msh.topology.index_map(0).size_local + msh.topology.index_map(0).num_ghosts
    out = np.zeros(n_vertices, dtype=np.int32)
    if dofs.size:
        out[c2v.array.reshape(dofs.shape)] = dofs
    return out


def all_local_edges(msh: mesh.Mesh) -> npt.NDArray[np.int32]:
    """Every local edge (for uniform refinement)."""
    msh.topology.create_entities(1)
    index_map = msh.topology.index_map(1)
    return np.arange(index_map.size_local + index_map.num_ghosts, dtype=np.int32)


#: The grading kept around the contact zone: a cell at distance d from it is split
#: while its diameter exceeds the zone's element size plus GRADING_SLOPE · d.
GRADING_SLOPE = 0.5


def graded_edges(
    msh: mesh.Mesh, center: npt.ArrayLike, radius: float, zone_size: float
) -> npt.NDArray[np.int32]:
    """The local edges of the cells too coarse for a mesh graded towards the contact zone.

    The stress field around a contact zone of radius a varies over lengths of a few a:
    refining the zone alone would leave its surroundings ever coarser relative to it,
    an error that stops shrinking while the level-to-level differences do (and the
    estimate of :mod:`admm_dolfinx.adapt.quantities` would pass it). A cell K whose
    diameter h_K exceeds ``zone_size`` + :data:`GRADING_SLOPE` · d_K, with d_K the
    distance of its midpoint beyond ``radius`` from ``center``, is split: the mesh
    then coarsens geometrically away from the zone, as a hand-graded mesh does.

    Args:
        msh: The mesh.
        center: The pressure peak.
        radius: The contact zone's radius around it.
        zone_size: The element size in the zone.

    Returns:
        Local edge indices.
    """
    tdim = msh.topology.dim
    index_map = msh.topology.index_map(tdim)
    cells = np.arange(index_map.size_local + index_map.num_ghosts, dtype=np.int32)
    if not cells.size:
        return np.zeros(0, dtype=np.int32)
    size = msh.h(tdim, cells)
    midpoints = mesh.compute_midpoints(msh, tdim, cells)[:, : msh.geometry.dim]
    c = np.asarray(center, dtype=np.float64)[: msh.geometry.dim]
    distance = np.maximum(np.linalg.norm(midpoints - c, axis=1) - radius, 0.0)
    coarse = cells[size > zone_size + GRADING_SLOPE * distance]
    msh.topology.create_connectivity(tdim, 1)
    c2e = msh.topology.connectivity(tdim, 1)
    return np.unique(c2e.array.reshape(cells.size, -1)[coarse]).astype(np.int32)


def count_edges(msh: mesh.Mesh, edges: npt.NDArray[np.int32]) -> int:
    """How many distinct edges of the whole mesh ``edges`` (local indices) marks; collective.

    An edge marked on several ranks (shared, or a ghost) counts once: the marks are
    summed onto each edge's owner, which counts it.
    """
    msh.topology.create_entities(1)
    index_map = msh.topology.index_map(1)
    marks = la.vector(index_map, 1)
    marks.array[:] = 0.0
    marks.array[np.asarray(edges, dtype=np.int64)] = 1.0
    marks.scatter_reverse(la.InsertMode.add)
    owned = int(np.count_nonzero(marks.array[: index_map.size_local] > 0.0))
    return int(msh.comm.allreduce(owned, op=MPI.SUM))
