"""The contact zone of a solution: the active set, its area, the pressure and the gap.

Every quantity is measured the way the method measures it: with the lumped contact
mass of the vertex rule, M_jj = ∫_Γc φ_j ds, so that the contact area times the mean
pressure is the magnitude of the normal contact force of
:func:`admm_dolfinx.problem.forces.contact_force` (exactly, for a flat obstacle).

A contact node j is *active* when its pressure λ_j is positive. A facet of Γ_C is in
contact when all its vertices are active. All functions are collective.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from dolfinx import fem, mesh
from mpi4py import MPI

from admm_dolfinx.problem.contact_problem import ContactProblem
from admm_dolfinx.problem.contact_set import marked_facets

__all__ = [
    "active_facets",
    "active_marker",
    "active_nodes",
    "contact_area",
    "gap_function",
    "mean_pressure",
]


def active_nodes(multiplier: npt.ArrayLike) -> npt.NDArray[np.bool_]:
    """Which owned contact nodes are active (λ_j > 0), shape (m_loc,)."""
    return np.asarray(multiplier, dtype=np.float64) > 0.0


def contact_area(problem: ContactProblem, multiplier: npt.ArrayLike) -> float:
    """The measure of the contact zone: Σ_j M_jj over the active nodes.

    An area in 3D and a length in 2D (per unit thickness), the same on every rank.
    """
    local = float(problem.contact.mass[active_nodes(multiplier)].sum())
    return float(problem.comm.allreduce(local, op=MPI.SUM))


def mean_pressure(problem: ContactProblem, multiplier: npt.ArrayLike) -> float:
    """The mean pressure over the contact zone, Σ M_jj λ_j / Σ_active M_jj (0 if none)."""
    lam = np.asarray(multiplier, dtype=np.float64)
    active = active_nodes(lam)
    c = problem.contact
    sums = problem.comm.allreduce(
        np.array([float((c.mass * lam)[active].sum()), float(c.mass[active].sum())]),
        op=MPI.SUM,
    )
    return float(sums[0] / sums[1]) if sums[1] > 0.0 else 0.0


def active_marker(problem: ContactProblem, multiplier: npt.ArrayLike) -> fem.Function:
    """A P1 (Q1) scalar Function: 1 at the active contact nodes, 0 elsewhere."""
    values = active_nodes(multiplier).astype(np.float64)
    return problem.pressure_function(values, name="active_set")


def _vertex_to_dof(problem: ContactProblem) -> npt.NDArray[np.int32]:
    """The local dof of the scalar contact space at each local vertex (-1: none)."""
    msh = problem.mesh
    tdim = msh.topology.dim
    msh.topology.create_connectivity(tdim, 0)
    cell_vertices = msh.topology.connectivity(tdim, 0)
    Q = problem.contact.Q
    dofs = Q.dofmap.list  # (num_cells, vertices per cell): P1/Q1 dofs are the vertices
    n_vertices = msh.topology.index_map(0).size_local + msh.topology.index_map(0).num_ghosts
    v2d = np.full(n_vertices, -1, dtype=np.int32)
    if dofs.size:
        vertices = cell_vertices.array.reshape(dofs.shape)
        v2d[vertices.ravel()] = dofs.ravel()
    return v2d


def active_facets(
    problem: ContactProblem, multiplier: npt.ArrayLike, value: int = 1
) -> mesh.MeshTags:
    """The facets of Γ_C in contact, as facet MeshTags (tag ``value``).

    A facet is in contact when every one of its vertices is an active contact node.
    Each rank tags its local facets (ghost facets included, consistently).
    """
    msh = problem.mesh
    fdim = msh.topology.dim - 1
    marker = active_marker(problem, multiplier).x.array  # ghosts updated
    facets = marked_facets(problem.facet_tags, problem.contact_marker)
    msh.topology.create_connectivity(fdim, 0)
    f2v = msh.topology.connectivity(fdim, 0)
    v2d = _vertex_to_dof(problem)
    per_facet = int(f2v.offsets[1] - f2v.offsets[0]) if f2v.offsets.size > 1 else 0
    dofs = (
        v2d[f2v.array.reshape(-1, per_facet)[facets]] if per_facet else np.empty((0, 0), np.int32)
    )
    keep = np.all(dofs >= 0, axis=1) & np.all(marker[dofs] > 0.5, axis=1)
    chosen = facets[keep].astype(np.int32)
    return mesh.meshtags(msh, fdim, chosen, np.full(chosen.size, value, dtype=np.int32))


def _remaining(values, normals, gap) -> npt.NDArray[np.float64]:
    """The remaining gap g − u·d per node (NaN where g = +inf: it can never touch)."""
    finite = np.isfinite(gap)
    moved = np.einsum("ij,ij->i", values, normals)
    return np.where(finite, np.where(finite, gap, 0.0) - moved, np.nan)


def gap_function(problem: ContactProblem, u: fem.Function) -> fem.Function:
    """The remaining gap g_j − (N u)_j on Γ_C as a P1 (Q1) scalar Function.

    Zero at nodes in contact, negative where a node penetrates the obstacle (by no
    more than the solver's tolerance), NaN where the obstacle can never be reached
    (an infinite gap); also at the nodes of Γ_C whose normal displacement a Dirichlet
    condition prescribes (they are not contact nodes, and may penetrate). Zero off Γ_C,
    where no gap is defined.
    """
    bs = problem.V.dofmap.index_map_bs
    c, gdim = problem.contact, problem.gdim
    displacement = u.x.array.reshape(-1, bs)
    f = problem.pressure_function(
        _remaining(displacement[c.nodes, :gdim], c.normals, c.gap), name="gap"
    )
    e = c.excluded
    f.x.array[e.dofs] = _remaining(displacement[e.nodes, :gdim], e.normals, e.gap)
    f.x.scatter_forward()
    return f
