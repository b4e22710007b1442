"""Vertex flags that every rank holding a copy of the vertex agrees on.

A rank sees only its own cells (and ghosts): a flag raised from a local facet or cell
(a vertex of Γ_C, a vertex of the contact zone's ring) is missing on a rank that holds
the vertex through another cell. Summed onto the owner and sent back to every copy
(a reverse then a forward scatter of a P1 function), the flag is the same everywhere,
so that decisions taken from it (which vertices move onto the true surface, which
cells are split) do not depend on the partition.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from dolfinx import fem, la, mesh

__all__ = ["agreed_geometry_flags", "agreed_vertex_flags"]


def _carrier(msh: mesh.Mesh) -> fem.Function:
    return fem.Function(fem.functionspace(msh, ("Lagrange", 1)))


def _agree(carrier: fem.Function) -> npt.NDArray[np.bool_]:
    carrier.x.scatter_reverse(la.InsertMode.add)
    carrier.x.scatter_forward()
    return carrier.x.array > 0.5


def _num_vertices(msh: mesh.Mesh) -> int:
    index_map = msh.topology.index_map(0)
    return index_map.size_local + index_map.num_ghosts


def _dof_of_vertex(msh: mesh.Mesh, V: fem.FunctionSpace) -> npt.NDArray[np.int32]:
    tdim = msh.topology.dim
    msh.topology.create_connectivity(tdim, 0)
    c2v = msh.topology.connectivity(tdim, 0)
    out = np.zeros(_num_vertices(msh), dtype=np.int32)
    dofs = V.dofmap.list
    if dofs.size:
        out[c2v.array.reshape(dofs.shape)] = dofs
    return out


def agreed_vertex_flags(msh: mesh.Mesh, vertices: npt.ArrayLike) -> npt.NDArray[np.bool_]:
    """Flags on the local topology vertices, raised wherever any rank raised them.

    Args:
        msh: An affine simplex mesh.
        vertices: Local vertex indices flagged on this rank.

    Returns:
        A boolean per local vertex (owned and ghost); collective.
    """
    carrier = _carrier(msh)
    dof = _dof_of_vertex(msh, carrier.function_space)
    carrier.x.array[dof[np.asarray(vertices, dtype=np.int64)]] = 1.0
    return _agree(carrier)[dof]


def agreed_geometry_flags(msh: mesh.Mesh, nodes: npt.ArrayLike) -> npt.NDArray[np.bool_]:
    """Flags on the local geometry nodes, raised wherever any rank raised them.

    Args:
        msh: An affine simplex mesh (its geometry nodes are its vertices).
        nodes: Local geometry node indices flagged on this rank.

    Returns:
        A boolean per local geometry node; collective.
    """
    carrier = _carrier(msh)
    dofs = carrier.function_space.dofmap.list
    node_of_dof = np.zeros(carrier.x.array.size, dtype=np.int64)
    if dofs.size:
        node_of_dof[dofs] = msh.geometry.dofmap
    dof_of_node = np.zeros(msh.geometry.x.shape[0], dtype=np.int64)
    dof_of_node[node_of_dof] = np.arange(node_of_dof.size)
    carrier.x.array[dof_of_node[np.asarray(nodes, dtype=np.int64)]] = 1.0
    return _agree(carrier)[dof_of_node]
