"""Layers of cells along Γ_C: the contact nodes and the rings of cells around them.

The local r* estimate takes the Schur complement of such a layer (the rest of the body
held fixed), and the surface metric calibrates on the contact nodes alone (zero rings).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from dolfinx import fem, la
from mpi4py import MPI
from petsc4py import PETSc

if TYPE_CHECKING:
    from admm_dolfinx.problem.contact_problem import ContactProblem

__all__ = ["contact_layer", "layer_index_set"]


def contact_layer(problem: ContactProblem, layers: int) -> tuple[np.ndarray, bool]:
    """Owned nodes within ``layers`` rings of cells of the contact nodes; collective.

    Args:
        problem: The contact problem.
        layers: Number of rings of cells around the contact nodes (0: the contact
            nodes alone).

    Returns:
        The sorted local node indices, and whether the layer is the whole mesh.
    """
    Q = problem.contact.Q
    marker = fem.Function(Q)
    marker.x.array[:] = 0.0
    marker.x.array[problem.contact.dofs] = 1.0
    marker.x.scatter_forward()
    cell_dofs = Q.dofmap.list
    for _ in range(layers):
        touched = marker.x.array[cell_dofs].max(axis=1) > 0.0
        grown = np.zeros_like(marker.x.array)
        grown[cell_dofs[touched].ravel()] = 1.0
        marker.x.array[:] = grown
        marker.x.scatter_reverse(la.InsertMode.add)
        marker.x.array[:] = np.minimum(marker.x.array, 1.0)
        marker.x.scatter_forward()
    n_owned = Q.dofmap.index_map.size_local
    owned = np.flatnonzero(marker.x.array[:n_owned] > 0.0)
    total = problem.comm.allreduce(owned.size, op=MPI.SUM)
    nodes = np.sort(problem.contact.q_to_node[owned])
    return nodes.astype(np.int32), total == Q.dofmap.index_map.size_global


def layer_index_set(problem: ContactProblem, nodes: np.ndarray) -> PETSc.IS:
    """The global dofs of a layer's nodes (:func:`contact_layer`), all bs per node.

    Args:
        problem: The contact problem.
        nodes: Owned local node indices.

    Returns:
        A distributed index set of A's rows (the caller destroys it).
    """
    bs = problem.V.dofmap.index_map_bs
    row0 = problem.A.getOwnershipRange()[0]
    dofs = (row0 + nodes[:, None] * bs + np.arange(bs)[None, :]).ravel()
    return PETSc.IS().createGeneral(dofs.astype(PETSc.IntType), comm=problem.comm)
