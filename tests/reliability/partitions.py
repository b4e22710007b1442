"""Meshes distributed in chosen, awkward ways, for the partition matrix of the tests.

Each builder creates a structured box (2D: triangles or quadrilaterals; 3D:
tetrahedra or hexahedra) on rank 0 and hands DOLFINx a partitioner that sends each
cell to the rank its centroid says:

* ``"default"``: DOLFINx's own partitioner;
* ``"no_contact_on_rank0"``: rank 0 holds cells of the upper half only, so it owns no
  contact node (Γ_C is the bottom face);
* ``"no_cells_on_last"``: the last rank holds no cell at all;
* ``"contact_on_one_rank"``: every cell of the bottom layer is on the last rank, so
  Γ_C lies on one rank only.
"""

from __future__ import annotations

import basix.ufl
import numpy as np
import ufl
from dolfinx import fem, graph, mesh
from mpi4py import MPI

from admm_dolfinx import ContactProblem, Obstacle, Plane
from admm_dolfinx.scenes.material import LinearElastic

PARTITIONS = ("default", "no_contact_on_rank0", "no_cells_on_last", "contact_on_one_rank")
CELLS = {2: ("triangle", "quadrilateral"), 3: ("tetrahedron", "hexahedron")}
#: Tags of the boxes' boundary parts.
BOTTOM, TOP = 1, 2


def _grid(gdim: int, cell: str, n: tuple[int, ...], lengths: tuple[float, ...]):
    """Nodes and cells of a structured box (simplices split from the boxes)."""
    axes = [np.linspace(0.0, length, k + 1) for length, k in zip(lengths, n, strict=True)]
    x = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, gdim)
    index = np.arange(x.shape[0]).reshape(tuple(k + 1 for k in n))
    if gdim == 2:
        v00, v10 = index[:-1, :-1].ravel(), index[1:, :-1].ravel()
        v01, v11 = index[:-1, 1:].ravel(), index[1:, 1:].ravel()
        if cell == "quadrilateral":
            cells = np.stack([v00, v10, v01, v11], axis=1)
        else:
            cells = np.concatenate(
                [np.stack([v00, v10, v11], axis=1), np.stack([v00, v11, v01], axis=1)]
            )
    else:
        c = [
            index[i : i + n[0], j : j + n[1], k : k + n[2]].ravel()
            for k in (0, 1)
            for j in (0, 1)
            for i in (0, 1)
        ]  # the 8 corners, lexicographic (x fastest): DOLFINx's hexahedron order
        if cell == "hexahedron":
            cells = np.stack(c, axis=1)
        else:  # six tetrahedra around the diagonal c0-c7
            paths = [(1, 3), (1, 5), (2, 3), (2, 6), (4, 5), (4, 6)]
            cells = np.concatenate([np.stack([c[0], c[a], c[b], c[7]], axis=1) for a, b in paths])
    return x, cells.astype(np.int64)


def _ranks(centroids: np.ndarray, how: str, size: int, height: float, h: float) -> np.ndarray:
    """The destination rank of each cell."""
    gdim = centroids.shape[1]
    up = centroids[:, gdim - 1]
    along = centroids[:, 0]
    span = along.max() - along.min() + 1e-12

    def by_x(ranks: list[int], mask: np.ndarray) -> np.ndarray:
        share = ((along[mask] - along.min()) / span * len(ranks)).astype(int)
        return np.asarray(ranks)[np.minimum(share, len(ranks) - 1)]

    dest = np.zeros(centroids.shape[0], dtype=np.int32)
    everyone = list(range(size))
    if how == "no_contact_on_rank0":
        upper = up > 0.5 * height
        dest[upper] = by_x(everyone if size > 1 else [0], upper) if size > 2 else 0
        dest[~upper] = by_x(everyone[1:] or [0], ~upper)
    elif how == "no_cells_on_last":
        dest[:] = by_x(everyone[:-1] or [0], np.ones(dest.size, dtype=bool))
    elif how == "contact_on_one_rank":
        bottom = up < h
        dest[bottom] = size - 1
        dest[~bottom] = by_x(everyone, ~bottom)
    else:
        raise ValueError(how)
    return dest


def box_mesh(
    comm: MPI.Comm, gdim: int, cell: str, how: str, n: tuple[int, ...], lengths: tuple[float, ...]
) -> mesh.Mesh:
    """A structured box distributed as ``how`` says (see the module docstring)."""
    x, cells = _grid(gdim, cell, n, lengths)
    if comm.rank != 0:
        x, cells = np.zeros((0, gdim)), np.zeros((0, cells.shape[1]), dtype=np.int64)
    element = basix.ufl.element("Lagrange", cell, 1, shape=(gdim,))
    partitioner = None
    if how != "default" and comm.size > 1:
        height, h = lengths[-1], lengths[-1] / n[-1]
        centroids = x[cells].mean(axis=1) if cells.size else np.zeros((0, gdim))
        dest = _ranks(centroids, how, comm.size, height, h) if cells.size else None

        def partitioner(_comm, nparts, _types, topology):
            local = dest if dest is not None else np.zeros(0, dtype=np.int32)
            return graph.adjacencylist(local.astype(np.int32))._cpp_object

    elif comm.size > 1:
        partitioner = mesh.create_cell_partitioner(mesh.GhostMode.shared_facet, 2)
    return mesh.create_mesh(comm, cells, ufl.Mesh(element), x, partitioner=partitioner)


def pressed_box(
    comm: MPI.Comm,
    gdim: int,
    cell: str,
    how: str,
    *,
    obstacle: Obstacle | None = None,
    n: tuple[int, ...] | None = None,
    push: float = 0.04,
    load: float | None = None,
    E: float = 1.0,
) -> ContactProblem:
    """A box whose top face is pushed down by ``push`` onto an obstacle under its bottom.

    With ``load``, the top face is pressed by a downward traction of that size instead
    and held only sideways: the box floats (its vertical translation and the rotations
    about axes in its top face cost no energy) and the contact alone holds it.
    """
    n = n or ((16, 6) if gdim == 2 else (6, 6, 4))
    lengths = (2.0, 0.5) if gdim == 2 else (1.0, 1.0, 0.5)
    msh = box_mesh(comm, gdim, cell, how, n, lengths)
    fdim = gdim - 1
    msh.topology.create_connectivity(fdim, gdim)
    bottom = mesh.locate_entities_boundary(msh, fdim, lambda x: np.isclose(x[gdim - 1], 0.0))
    top = mesh.locate_entities_boundary(msh, fdim, lambda x: np.isclose(x[gdim - 1], lengths[-1]))
    facets = np.concatenate([bottom, top])
    values = np.concatenate([np.full(bottom.size, BOTTOM), np.full(top.size, TOP)])
    order = np.argsort(facets)
    tags = mesh.meshtags(msh, fdim, facets[order].astype(np.int32), values[order].astype(np.int32))
    V = fem.functionspace(msh, ("Lagrange", 1, (gdim,)))
    u, v = ufl.TrialFunction(V), ufl.TestFunction(V)
    down = np.zeros(gdim)
    zero = fem.Constant(msh, np.zeros(gdim))
    if load is None:
        down[-1] = -push
        bcs = [fem.dirichletbc(down, fem.locate_dofs_topological(V, fdim, tags.find(TOP)), V)]
        force = ufl.dot(zero, v) * ufl.dx
    else:
        bcs = []
        for i in range(gdim - 1):  # the top face held sideways only
            Vi = V.sub(i)
            dofs = fem.locate_dofs_topological(Vi, fdim, tags.find(TOP))
            bcs.append(fem.dirichletbc(fem.Constant(msh, 0.0), dofs, Vi))
        down[-1] = -load
        ds = ufl.Measure("ds", msh, subdomain_data=tags)
        force = ufl.dot(fem.Constant(msh, down), v) * ds(TOP)
    if obstacle is None:
        normal = np.zeros(gdim)
        normal[-1] = 1.0
        obstacle = Plane(np.full(gdim, 0.0) - 0.01 * normal, normal)
    return ContactProblem(
        LinearElastic(E, 0.3).bilinear_form(u, v),
        force,
        bcs,
        tags,
        BOTTOM,
        obstacle,
    )


def gathered(problem: ContactProblem, function: fem.Function) -> np.ndarray:
    """Nodal values of a P1 function on every rank, sorted by node coordinates."""
    V = function.function_space
    comm = V.mesh.comm
    n_owned = V.dofmap.index_map.size_local
    bs = V.dofmap.index_map_bs
    coords = np.concatenate(comm.allgather(V.tabulate_dof_coordinates()[:n_owned]))
    values = np.concatenate(comm.allgather(function.x.array[: n_owned * bs].reshape(n_owned, bs)))
    order = np.lexsort(np.round(coords, 10).T[::-1])
    return values[order]


def owners(problem: ContactProblem) -> dict[str, list[int]]:
    """Contact nodes and cells per rank (to check that the partition is what it says)."""
    comm = problem.comm
    tdim = problem.mesh.topology.dim
    return {
        "contact": comm.allgather(int(problem.contact.dofs.size)),
        "cells": comm.allgather(int(problem.mesh.topology.index_map(tdim).size_local)),
    }
