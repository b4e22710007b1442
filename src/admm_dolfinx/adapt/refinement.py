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

from admm_dolfinx.adapt.estimator import Surface
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
) -> tuple[mesh.Mesh, mesh.MeshTags]:
    """Split ``edges``, carry the facet tags, place Γ_C's vertices on ``surface``; collective.

    Args:
        msh: The mesh.
        facet_tags: Its facet tags.
        edges: The local edges to split (the refinement shares them with other ranks).
        contact_marker: The tag(s) of Γ_C, whose vertices go onto ``surface``.
        surface: The body's true surface near Γ_C, as a map from points (k, gdim) to
            the nearest points on it; None keeps the mesh's facets as the surface.

    Returns:
        The refined mesh and its facet tags.
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
    tags = _transfer_facet_tags(facet_tags, msh, fine, parent_cell, parent_facet)
    if surface is not None:
        fine.topology.create_connectivity(fdim, fine.topology.dim)
        facets = marked_facets(tags, contact_marker)
        nodes = np.unique(mesh.entities_to_geometry(fine, fdim, facets).ravel())
        gdim = fine.geometry.dim
        if nodes.size:
            moved = np.asarray(surface(fine.geometry.x[nodes, :gdim]), dtype=np.float64)
            if moved.shape != (nodes.size, gdim) or not np.all(np.isfinite(moved)):
                raise ValueError(
                    "`surface` must map points of shape (k, gdim) to finite points of the "
                    f"same shape; got shape {moved.shape} for {nodes.size} points."
                )
            fine.geometry.x[nodes, :gdim] = moved
    return fine, tags


def _transfer_facet_tags(
    tags: mesh.MeshTags,
    coarse: mesh.Mesh,
    fine: mesh.Mesh,
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
    # the parent maps are indexed by the refined cells' input order, which the new
    # mesh's topology reorders: original_cell_index undoes that
    # (global input indices in parallel: each rank's refined cells come in rank order)
    count = int(np.size(parent_cell))
    start = fine.comm.exscan(count) if fine.comm.size > 1 else 0
    owned = fine.topology.index_map(tdim).size_local
    order = np.asarray(fine.topology.original_cell_index, dtype=np.int64)[:owned] - (start or 0)
    if order.size and (order.min() < 0 or order.max() >= count):
        raise RuntimeError(  # pragma: no cover - a refinement that moved cells
            "internal: the refined mesh's cells are not those refined on this process"
        )
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


def transfer_solution(result: ADMMResult, problem: ContactProblem) -> WarmStart:
    """A coarse solution interpolated onto a finer problem, to start its solve; collective.

    Points of the fine mesh that the coarse one does not cover (vertices moved onto a
    convex true surface) get zero.

    Args:
        result: The coarse solution.
        problem: The problem on the refined mesh.

    Returns:
        u and λ on the fine problem.
    """
    fine = problem.mesh
    tdim = fine.topology.dim
    cell_map = fine.topology.index_map(tdim)
    cells = np.arange(cell_map.size_local + cell_map.num_ghosts, dtype=np.int32)
    u = fem.Function(problem.V)
    data = fem.create_interpolation_data(problem.V, result.u.function_space, cells, padding=1e-8)
    u.interpolate_nonmatching(result.u, cells, data)
    pressure = fem.Function(problem.contact.Q)
    data = fem.create_interpolation_data(
        problem.contact.Q, result.pressure.function_space, cells, padding=1e-8
    )
    pressure.interpolate_nonmatching(result.pressure, cells, data)
    multiplier = np.maximum(pressure.x.array[problem.contact.dofs], 0.0)
    return WarmStart(u, multiplier)
