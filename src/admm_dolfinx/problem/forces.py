"""Resultant forces of a solution: the contact force and the reaction on a boundary part.

Both are the discrete forces of the solved system, so they balance to round-off. The
contact force is assembled from λ the way the method uses it (the lumped mass of the
vertex rule: F_c = −Σ_j M_jj λ_j d_j, d_j the contact direction); integrating the
pressure field with another quadrature would not match the reactions. The reaction
on a boundary part is the residual a(u, φ_i) − L(φ_i) − F_c,i summed over the dofs of
the part's facets: the force its support exerts on the body.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
import ufl
from dolfinx import fem
from dolfinx.fem import petsc as fem_petsc
from mpi4py import MPI
from petsc4py import PETSc

from admm_dolfinx.problem.contact_problem import ContactProblem
from admm_dolfinx.problem.contact_set import Marker, as_marker, marked_facets

__all__ = ["contact_force", "reaction_force"]


def _nodal_contact_force(problem: ContactProblem, multiplier) -> npt.NDArray[np.float64]:
    """−M_jj λ_j d_j at the owned contact nodes, shape (m_loc, gdim)."""
    c = problem.contact
    lam = np.asarray(multiplier, dtype=np.float64)
    return -(c.mass * lam)[:, None] * c.normals


def contact_force(problem: ContactProblem, multiplier: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """The total force of the obstacle on the body, a gdim vector; collective.

    Args:
        problem: The contact problem.
        multiplier: λ at the owned contact nodes (``result.multiplier``).

    Returns:
        F_c = −Σ_j M_jj λ_j d_j, the same on every rank.
    """
    local = _nodal_contact_force(problem, multiplier).sum(axis=0)
    return np.asarray(problem.comm.allreduce(local, op=MPI.SUM), dtype=np.float64)


def reaction_force(
    problem: ContactProblem,
    u: fem.Function,
    marker: Marker,
    multiplier: npt.ArrayLike | None = None,
) -> npt.NDArray[np.float64]:
    """The force on the body from the supports on the facets tagged ``marker``; collective.

    Args:
        problem: The contact problem (its forms and facet tags).
        u: The displacement (``result.u``).
        marker: A facet tag of ``problem.facet_tags`` (typically a Dirichlet part), or a
            tuple of tags.
        multiplier: λ (``result.multiplier``), to take the contact force out at nodes
            the part shares with Γ_C.

    Returns:
        Σ over the part's dofs of a(u, φ_i) − L(φ_i) − F_c,i, a gdim vector.

    Raises:
        ValueError: If no rank has a facet with ``marker``.
    """
    V, msh = problem.V, problem.mesh
    fdim = msh.topology.dim - 1
    marker = as_marker(marker, "marker")
    facets = marked_facets(problem.facet_tags, marker)
    if problem.comm.allreduce(facets.size, op=MPI.SUM) == 0:
        raise ValueError(f"No facets are tagged {marker}; pass a tag of problem.facet_tags.")
    bs = V.dofmap.index_map_bs
    residual = fem_petsc.assemble_vector(fem.form(ufl.action(problem._a_ufl, u) - problem._L_ufl))
    residual.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
    try:
        values = residual.array_r.reshape(-1, bs).copy()
    finally:
        residual.destroy()
    if multiplier is not None:
        c = problem.contact
        values[c.nodes, : problem.gdim] -= _nodal_contact_force(problem, multiplier)
    msh.topology.create_connectivity(fdim, msh.topology.dim)
    nodes = fem.locate_dofs_topological(V.sub(0), fdim, facets) // bs
    owned = nodes[nodes < V.dofmap.index_map.size_local]
    local = values[np.unique(owned), : problem.gdim].sum(axis=0)
    return np.asarray(problem.comm.allreduce(local, op=MPI.SUM), dtype=np.float64)
