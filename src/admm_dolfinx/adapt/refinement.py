"""One level finer: split the marked edges, carry the tags, place Γ_C on the true surface.

:func:`refine_contact_mesh` splits the marked edges (and whatever else keeps the
mesh conforming: ``dolfinx.mesh.refine``, Plaza's algorithm, on simplices), carries
the facet tags to the new mesh (``dolfinx.mesh.transfer_meshtag``) and, if the body's
true surface is given, moves the vertices of Γ_C onto it: a new vertex sits at the
midpoint of a straight edge, so a curved body would otherwise keep the coarse mesh's
polygon, and a polygon against a plane is a row of flat punches, whose pressure has
no peak to converge to. :func:`transfer_solution` interpolates a coarse solution onto
the new mesh to start its solve.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from dolfinx import fem, mesh
from mpi4py import MPI

from admm_dolfinx.adapt.shared_vertices import agreed_geometry_flags
from admm_dolfinx.adapt.surface import Surface, project_on_surface
from admm_dolfinx.admm.result import ADMMResult, WarmStart
from admm_dolfinx.problem.contact_problem import ContactProblem
from admm_dolfinx.problem.contact_set import Marker, marked_facets

__all__ = ["check_refinable", "refine_contact_mesh", "transfer_solution"]


def check_refinable(msh: mesh.Mesh) -> None:
    """Raise unless ``msh`` is a mesh that ``dolfinx.mesh.refine`` refines.

    Raises:
        ValueError: For quadrilaterals and hexahedra, or curved (higher-order) geometry.
    """
    cell = msh.topology.cell_name()
    if cell not in ("triangle", "tetrahedron"):
        raise ValueError(
            f"solve_adaptive refines simplices (dolfinx.mesh.refine); this mesh has "
            f"{cell}s. Mesh the body with triangles or tetrahedra (gmsh: the default), or "
            "refine a mesh of these cells by hand and solve each with ADMMSolver."
        )
    degree = msh.geometry.cmap.degree
    if degree != 1:
        raise ValueError(
            f"solve_adaptive refines affine meshes; this one has geometry of degree {degree} "
            "(curved cells). Use a degree-1 mesh and give the body's true surface as "
            "`surface=` instead: the new vertices of the contact boundary are placed on it."
        )


def refine_contact_mesh(
    msh: mesh.Mesh,
    facet_tags: mesh.MeshTags,
    edges: npt.NDArray[np.int32],
    contact_marker: Marker,
    surface: Surface | None = None,
) -> tuple[mesh.Mesh, mesh.MeshTags, npt.NDArray[np.int32]]:
    """Split ``edges``, carry the facet tags, place Γ_C's vertices on ``surface``; collective.

    Args:
        msh: The mesh.
        facet_tags: Its facet tags.
        edges: The local edges to split (the refinement shares them with other ranks).
        contact_marker: The tag(s) of Γ_C, whose vertices go onto ``surface``.
        surface: The body's true surface near Γ_C, as a map from points (k, gdim) to
            the nearest points on it; None keeps the mesh's facets as the surface.

    Returns:
        The refined mesh, its facet tags, and the parent of each of its owned cells (a
        local cell of ``msh``: refinement keeps a cell's children on its process).
    """
    fdim = msh.topology.dim - 1
    msh.topology.create_entities(1)
    msh.topology.create_connectivity(fdim, msh.topology.dim)
    fine, parent_cell, parent_facet = mesh.refine(
        msh, edges, option=mesh.RefinementOption.parent_cell_and_facet
    )
    fine.topology.create_entities(fdim)
    # what a user's build() may need, as on a mesh read from gmsh (locate_dofs_topological)
    fine.topology.create_connectivity(fdim, fine.topology.dim)
    order = _refined_order(fine, parent_cell)
    tags = _transfer_facet_tags(facet_tags, msh, fine, order, parent_cell, parent_facet)
    if surface is not None:
        _place_on_surface(fine, marked_facets(tags, contact_marker), surface)
    return fine, tags, np.asarray(parent_cell, dtype=np.int32)[order]


def _place_on_surface(fine: mesh.Mesh, facets: npt.NDArray[np.int32], surface: Surface) -> None:
    """Move the vertices of ``facets`` onto ``surface``, every copy of a vertex alike."""
    fdim = fine.topology.dim - 1
    local = (
        mesh.entities_to_geometry(fine, fdim, facets).ravel()
        if facets.size
        else np.zeros(0, dtype=np.int64)
    )
    # a rank may hold a vertex of Γ_C through a cell that does not hold the facet
    nodes = np.flatnonzero(agreed_geometry_flags(fine, local))
    gdim = fine.geometry.dim
    moved = project_on_surface(fine.comm, surface, fine.geometry.x[nodes, :gdim])
    fine.geometry.x[nodes, :gdim] = moved


def _refined_order(fine: mesh.Mesh, parent_cell: npt.NDArray[np.int32]) -> npt.NDArray[np.int64]:
    """For each owned cell of ``fine``, its index in the refinement's parent maps.

    The parent maps are indexed by the refined cells' input order, which the new mesh's
    topology reorders: ``original_cell_index`` undoes that (global input indices in
    parallel: each rank's refined cells come in rank order).
    """
    tdim = fine.topology.dim
    count = int(np.size(parent_cell))
    start = fine.comm.exscan(count) if fine.comm.size > 1 else 0
    owned = fine.topology.index_map(tdim).size_local
    order = np.asarray(fine.topology.original_cell_index, dtype=np.int64)[:owned] - (start or 0)
    if order.size and (order.min() < 0 or order.max() >= count):
        raise RuntimeError(  # pragma: no cover - a refinement that moved cells
            "internal: the refined mesh's cells are not those refined on this process"
        )
    return order


def _transfer_facet_tags(
    tags: mesh.MeshTags,
    coarse: mesh.Mesh,
    fine: mesh.Mesh,
    order: npt.NDArray[np.int64],
    parent_cell: npt.NDArray[np.int32],
    parent_facet: npt.NDArray[np.int8],
) -> mesh.MeshTags:
    """The coarse facet tags on the refined mesh: each child facet takes its parent's tag.

    ``dolfinx.mesh.transfer_meshtag`` refuses ghosted meshes (gmsh's partitioner makes
    them); this reads the same parent maps on any mesh: a fine cell's local facet i
    lies in its parent cell's local facet ``parent_facet[cell, i]`` (−1: inside it).
    """
    tdim = coarse.topology.dim
    fdim = tdim - 1
    coarse.topology.create_connectivity(tdim, fdim)
    fine.topology.create_connectivity(tdim, fdim)
    coarse_map = coarse.topology.index_map(fdim)
    value_of = np.full(coarse_map.size_local + coarse_map.num_ghosts, -1, dtype=np.int64)
    value_of[tags.indices] = tags.values
    per_cell = tdim + 1
    coarse_c2f = coarse.topology.connectivity(tdim, fdim).array.reshape(-1, per_cell)
    fine_c2f = fine.topology.connectivity(tdim, fdim).array.reshape(-1, per_cell)
    n = min(order.size, fine_c2f.shape[0])
    fine_c2f, order = fine_c2f[:n], order[:n]
    local = np.asarray(parent_facet, dtype=np.int64).reshape(-1, per_cell)[order]
    cells = np.asarray(parent_cell, dtype=np.int64)[order]
    inside = local < 0
    parents = coarse_c2f[cells[:, None], np.where(inside, 0, local)]
    values = np.where(inside, -1, value_of[parents])
    tagged = values >= 0
    facets, first = np.unique(fine_c2f[tagged], return_index=True)
    return mesh.meshtags(
        fine, fdim, facets.astype(np.int32), values[tagged][first].astype(np.int32)
    )


#: The interpolation's padding, as a share of the coarse mesh's smallest cell.
PADDING_SHARE = 0.1


def _smallest_cell(msh: mesh.Mesh) -> float:
    """The smallest cell diameter of the whole mesh; collective."""
    tdim = msh.topology.dim
    n = msh.topology.index_map(tdim).size_local
    local = float(np.min(msh.h(tdim, np.arange(n, dtype=np.int32)))) if n else np.inf
    return float(msh.comm.allreduce(local, op=MPI.MIN))


def transfer_solution(
    result: ADMMResult,
    problem: ContactProblem,
    parents: npt.NDArray[np.int32] | None = None,
) -> WarmStart:
    """A coarse solution interpolated onto a finer problem, to start its solve; collective.

    With ``parents`` (from :func:`refine_contact_mesh`, the fine mesh being a refinement
    of the coarse solution's), each fine cell's interpolation points are evaluated in
    its parent cell: no search. Without, or where the meshes are not those, the points
    are located in the coarse mesh (``dolfinx.fem.create_interpolation_data``). Either
    way, points of the fine mesh just outside the coarse one (vertices moved onto a
    convex true surface) take the values of the coarse cell they came from (its
    polynomial extended), or of their nearest coarse cell.

    Args:
        result: The coarse solution.
        problem: The problem on the refined mesh.
        parents: The coarse parent (local cell) of each owned cell of the fine mesh.

    Returns:
        u and λ on the fine problem.
    """
    u = fem.Function(problem.V)
    pressure = fem.Function(problem.contact.Q)
    owned = problem.mesh.topology.index_map(problem.mesh.topology.dim).size_local
    related = problem.mesh.comm.allreduce(
        parents is not None and parents.size == owned, op=MPI.LAND
    )
    if related:
        assert parents is not None
        for target, source in ((u, result.u), (pressure, result.pressure)):
            _interpolate_in_parents(target, source, parents)
    else:
        _interpolate_by_search(u, result.u)
        _interpolate_by_search(pressure, result.pressure)
    multiplier = np.maximum(pressure.x.array[problem.contact.dofs], 0.0)
    return WarmStart(u, multiplier)


def _interpolate_in_parents(
    target: fem.Function, source: fem.Function, parents: npt.NDArray[np.int32]
) -> None:
    """``source`` at the interpolation points of each owned cell, in its parent; collective.

    The owned cells of ``target``'s mesh are interpolated, its ghosts then take the
    values of their owners.
    """
    cells = np.arange(parents.size, dtype=np.int32)

    def values(x: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        per_cell = x.shape[1] // max(cells.size, 1)
        at = source.eval(x.T, np.repeat(parents, per_cell).astype(np.int32))
        return np.ascontiguousarray(at.T)

    target.interpolate(values, cells0=cells)
    target.x.scatter_forward()


def _interpolate_by_search(target: fem.Function, source: fem.Function) -> None:
    """``source`` interpolated onto ``target``'s mesh by locating its points; collective."""
    fine = target.function_space.mesh
    tdim = fine.topology.dim
    cell_map = fine.topology.index_map(tdim)
    cells = np.arange(cell_map.size_local + cell_map.num_ghosts, dtype=np.int32)
    # vertices moved onto a convex true surface lie outside the coarse mesh, by the
    # sagitta of its facets (h²/8R): a padding of a fraction of the smallest coarse
    # cell finds them their nearest coarse cell instead of leaving them at zero
    padding = PADDING_SHARE * _smallest_cell(source.function_space.mesh)
    data = fem.create_interpolation_data(
        target.function_space, source.function_space, cells, padding=padding
    )
    target.interpolate_nonmatching(source, cells, data)
