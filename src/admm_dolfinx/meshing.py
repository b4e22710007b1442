"""gmsh geometry for the scenes: built on rank 0, distributed by DOLFINx.

Each builder returns a :class:`MeshData` with the mesh and its facet tags; boundary
parts are tagged with the integers the scene declares.  Only this module imports
gmsh, so the solver never depends on it.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator

import numpy as np
from dolfinx import mesh
from dolfinx.io import gmsh as gmshio
from mpi4py import MPI

__all__ = ["MeshData", "build_on_root", "gmsh_session", "rectangle", "structured_rectangle", "tag_boundary"]

MeshData = gmshio.MeshData


def _import_gmsh():
    try:
        import gmsh
    except ImportError as err:  # pragma: no cover - depends on the environment
        raise ImportError(
            "The scenes build their meshes with gmsh: `pip install 'admm-dolfinx[scenes]'`."
        ) from err
    return gmsh


@contextlib.contextmanager
def gmsh_session(name: str) -> Iterator[object]:
    """Initialise gmsh quietly with a fresh model, and finalise it afterwards.

    Args:
        name: Model name.

    Yields:
        The ``gmsh`` module.
    """
    gmsh = _import_gmsh()
    owner = not gmsh.isInitialized()
    if owner:
        gmsh.initialize(interruptible=False)
    gmsh.option.setNumber("General.Terminal", 0)
    gmsh.option.setNumber("General.Verbosity", 1)
    gmsh.model.add(name)
    try:
        yield gmsh
    finally:
        gmsh.model.remove()
        if owner:
            gmsh.finalize()


def build_on_root(
    comm: MPI.Comm, name: str, gdim: int, build: Callable[[object], None]
) -> MeshData:
    """Run ``build(gmsh)`` on rank 0 and distribute the mesh over ``comm``.

    Args:
        comm: Communicator of the mesh.
        name: gmsh model name.
        gdim: Geometric dimension.
        build: Creates geometry, physical groups and the mesh in the current model.

    Returns:
        DOLFINx mesh data (mesh, cell tags, facet tags).
    """
    with gmsh_session(name) as gmsh:
        if comm.rank == 0:
            build(gmsh)
        data = gmshio.model_to_mesh(gmsh.model, comm, 0, gdim=gdim)
    return data


def _tag_curves_by_center(gmsh, dim: int, rules: dict[int, Callable[[np.ndarray], bool]]):
    """Put each boundary entity of dimension ``dim`` in the physical group whose rule matches."""
    groups: dict[int, list[int]] = {tag: [] for tag in rules}
    for _, entity in gmsh.model.getEntities(dim):
        center = np.asarray(gmsh.model.occ.getCenterOfMass(dim, entity))
        for tag, rule in rules.items():
            if rule(center):
                groups[tag].append(entity)
                break
    for tag, entities in groups.items():
        if entities:
            gmsh.model.addPhysicalGroup(dim, entities, tag)


def rectangle(
    comm: MPI.Comm,
    corner: tuple[float, float],
    size: tuple[float, float],
    h: float,
    tags: dict[str, int],
) -> MeshData:
    """Unstructured triangle mesh of a rectangle with its four sides tagged.

    Args:
        comm: Communicator.
        corner: Lower-left corner (x0, y0).
        size: Width and height.
        h: Target element size.
        tags: Tags of the sides, keys ``"left"``, ``"right"``, ``"bottom"``, ``"top"``.

    Returns:
        Mesh data.
    """
    x0, y0 = corner
    w, ht = size

    def build(gmsh):
        surface = gmsh.model.occ.addRectangle(x0, y0, 0.0, w, ht)
        gmsh.model.occ.synchronize()
        gmsh.model.addPhysicalGroup(2, [surface], 1)
        eps = 1e-8 * max(w, ht)
        _tag_curves_by_center(
            gmsh,
            1,
            {
                tags["left"]: lambda c: abs(c[0] - x0) < eps,
                tags["right"]: lambda c: abs(c[0] - x0 - w) < eps,
                tags["bottom"]: lambda c: abs(c[1] - y0) < eps,
                tags["top"]: lambda c: abs(c[1] - y0 - ht) < eps,
            },
        )
        gmsh.option.setNumber("Mesh.MeshSizeMin", h)
        gmsh.option.setNumber("Mesh.MeshSizeMax", h)
        gmsh.option.setNumber("Mesh.Algorithm", 6)  # Frontal-Delaunay
        gmsh.model.mesh.generate(2)

    return build_on_root(comm, "rectangle", 2, build)


def structured_rectangle(
    comm: MPI.Comm,
    corner: tuple[float, float],
    size: tuple[float, float],
    cells: tuple[int, int],
    tags: dict[str, int],
) -> tuple[mesh.Mesh, mesh.MeshTags]:
    """Structured (DOLFINx built-in) triangle mesh of a rectangle with tagged sides.

    Args:
        comm: Communicator.
        corner: Lower-left corner.
        size: Width and height.
        cells: Number of cells along x and y.
        tags: As for :func:`rectangle`.

    Returns:
        The mesh and its facet tags.
    """
    x0, y0 = corner
    w, ht = size
    msh = mesh.create_rectangle(
        comm, [np.array([x0, y0]), np.array([x0 + w, y0 + ht])], list(cells)
    )
    rules = {
        tags["left"]: lambda x: np.isclose(x[0], x0),
        tags["right"]: lambda x: np.isclose(x[0], x0 + w),
        tags["bottom"]: lambda x: np.isclose(x[1], y0),
        tags["top"]: lambda x: np.isclose(x[1], y0 + ht),
    }
    return msh, tag_boundary(msh, rules)


def tag_boundary(
    msh: mesh.Mesh, rules: dict[int, Callable[[np.ndarray], np.ndarray]]
) -> mesh.MeshTags:
    """Tag boundary facets by geometric rules (first matching rule wins).

    Args:
        msh: The mesh.
        rules: Tag value → marker function of the facet's vertices (DOLFINx style).

    Returns:
        Facet tags.
    """
    fdim = msh.topology.dim - 1
    msh.topology.create_connectivity(fdim, fdim + 1)
    indices, values = [], []
    taken = np.zeros(0, dtype=np.int32)
    for tag, rule in rules.items():
        facets = mesh.locate_entities_boundary(msh, fdim, rule)
        facets = np.setdiff1d(facets, taken)
        taken = np.union1d(taken, facets)
        indices.append(facets)
        values.append(np.full(facets.size, tag, dtype=np.int32))
    idx = np.concatenate(indices).astype(np.int32)
    val = np.concatenate(values)
    order = np.argsort(idx)
    return mesh.meshtags(msh, fdim, idx[order], val[order])
