"""gmsh geometry for the scenes: built on rank 0, distributed by DOLFINx.

Each builder returns a :class:`MeshData` with the mesh and its facet tags; boundary
parts are tagged with the integers the scene declares.  Only this module imports
gmsh, so the solver never depends on it.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Callable, Iterator
from types import ModuleType

import numpy as np
from dolfinx import mesh
from dolfinx.io import gmsh as gmshio
from mpi4py import MPI

from admm_dolfinx._mpi import run_on_rank0

__all__ = [
    "MeshData",
    "box",
    "build_on_root",
    "check_lengths",
    "check_level",
    "gmsh_session",
    "lower_ball",
    "mesh_and_facet_tags",
    "punch_block",
    "quarter_disc",
    "rectangle",
    "structured_rectangle",
    "tag_boundary",
]

MeshData = gmshio.MeshData


def mesh_and_facet_tags(data: MeshData) -> tuple[mesh.Mesh, mesh.MeshTags]:
    """The mesh and the facet tags of gmsh mesh data (the scenes tag their boundaries).

    Args:
        data: What :func:`build_on_root` returned.

    Returns:
        The mesh and its facet tags.

    Raises:
        RuntimeError: If the gmsh model had no physical groups of facets.
    """
    if data.facet_tags is None:
        raise RuntimeError("The gmsh mesh has no facet tags (no physical groups of facets).")
    return data.mesh, data.facet_tags


def check_lengths(**lengths: float | None) -> None:
    """Raise a ValueError naming any length that is not a positive finite number.

    ``None`` values (optional lengths) are skipped. gmsh itself would fail with a
    less clear message, or, for a graded size field, abort the process.
    """
    for name, value in lengths.items():
        if value is None:
            continue
        ok = isinstance(value, int | float | np.floating | np.integer) and not isinstance(
            value, bool
        )
        if not (ok and math.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be a positive finite length, got {value!r}.")


def check_level(name: str, value: int) -> int:
    """Return ``value`` if it is an integer ≥ 0, else raise a ValueError naming it."""
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 0:
        raise ValueError(f"{name} must be an integer ≥ 0 (0: the coarsest mesh), got {value!r}.")
    return int(value)


def _import_gmsh() -> ModuleType:
    from admm_dolfinx._extras import require

    return require("gmsh", "The scenes build their meshes with gmsh")


@contextlib.contextmanager
def gmsh_session(name: str) -> Iterator[ModuleType]:
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
    comm: MPI.Comm, name: str, gdim: int, build: Callable[[ModuleType], None]
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

        def failure(kind: str, text: str, _: bool) -> Exception:
            return RuntimeError(f"gmsh could not build the {name!r} mesh: {kind}: {text}")

        run_on_rank0(comm, lambda: build(gmsh), failure)
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
    check_lengths(h=h, width=w, height=ht)

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


def quarter_disc(
    comm: MPI.Comm,
    radius: float,
    h: float,
    h_contact: float,
    tags: dict[str, int],
    *,
    refine_radius: float | None = None,
) -> MeshData:
    """The lower-right quarter of a disc of radius R centred at (0, R).

    Sides: ``"axis"`` (x = 0, the symmetry line), ``"top"`` (y = R, through the
    centre) and ``"arc"`` (the curved part, which touches y = 0 at the origin).

    Args:
        comm: Communicator.
        radius: R.
        h: Element size away from the arc.
        h_contact: Element size on the arc.
        tags: Tags of ``"axis"``, ``"top"``, ``"arc"``.
        refine_radius: If given, ``h_contact`` applies only within this distance of the
            lowest point (0, 0), where a Hertz contact zone forms, growing to ``h`` at
            three times the distance; otherwise along the whole arc.

    Returns:
        Mesh data.
    """
    check_lengths(radius=radius, h=h, h_contact=h_contact, refine_radius=refine_radius)
    R = radius

    def build(gmsh):
        disc = gmsh.model.occ.addDisk(0.0, R, 0.0, R, R)
        box = gmsh.model.occ.addRectangle(0.0, 0.0, 0.0, R, R)
        out, _ = gmsh.model.occ.intersect([(2, disc)], [(2, box)])
        gmsh.model.occ.synchronize()
        gmsh.model.addPhysicalGroup(2, [e for _, e in out], 1)
        eps = 1e-8 * R
        _tag_curves_by_center(
            gmsh,
            1,
            {
                tags["axis"]: lambda c: abs(c[0]) < eps,
                tags["top"]: lambda c: abs(c[1] - R) < eps,
                tags["arc"]: lambda c: True,
            },
        )
        arc = gmsh.model.getEntitiesForPhysicalGroup(1, tags["arc"])
        field = gmsh.model.mesh.field
        dist = field.add("Distance")
        thr = field.add("Threshold")
        if refine_radius is None:
            field.setNumbers(dist, "CurvesList", list(arc))
            field.setNumber(dist, "Sampling", 200)
            field.setNumber(thr, "DistMin", 0.0)
            field.setNumber(thr, "DistMax", 0.5 * R)
        else:
            lowest = [
                tag
                for _, tag in gmsh.model.getEntities(0)
                if np.linalg.norm(gmsh.model.getValue(0, tag, [])) < 1e-8 * R
            ]
            field.setNumbers(dist, "PointsList", lowest)
            field.setNumber(thr, "DistMin", refine_radius)
            field.setNumber(thr, "DistMax", 3.0 * refine_radius + 4.0 * h)
        field.setNumber(thr, "InField", dist)
        field.setNumber(thr, "SizeMin", h_contact)
        field.setNumber(thr, "SizeMax", h)
        field.setAsBackgroundMesh(thr)
        gmsh.option.setNumber("Mesh.MeshSizeExtendFromBoundary", 0)
        gmsh.option.setNumber("Mesh.MeshSizeFromPoints", 0)
        gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", 0)
        gmsh.option.setNumber("Mesh.Algorithm", 6)
        gmsh.model.mesh.generate(2)

    return build_on_root(comm, "quarter_disc", 2, build)


def box(
    comm: MPI.Comm,
    lower: tuple[float, float, float],
    upper: tuple[float, float, float],
    h_bottom: float,
    h_top: float,
    refinements: int,
    tags: dict[str, int],
) -> MeshData:
    """Tetrahedral mesh of a box, graded from ``h_bottom`` (z = z0) to ``h_top``.

    Faces: ``"bottom"``, ``"top"`` and ``"sides"``. The mesh is then split uniformly
    ``refinements`` times by gmsh (each split: 8 children per tetrahedron).

    Args:
        comm: Communicator.
        lower: (x0, y0, z0).
        upper: (x1, y1, z1).
        h_bottom: Element size on the bottom face.
        h_top: Element size on the top face.
        refinements: Uniform refinements after generation.
        tags: Tags of ``"bottom"``, ``"top"``, ``"sides"``.

    Returns:
        Mesh data.
    """
    check_lengths(h_bottom=h_bottom, h_top=h_top)
    refinements = check_level("refinements", refinements)
    x0, y0, z0 = lower
    x1, y1, z1 = upper

    def build(gmsh):
        vol = gmsh.model.occ.addBox(x0, y0, z0, x1 - x0, y1 - y0, z1 - z0)
        gmsh.model.occ.synchronize()
        gmsh.model.addPhysicalGroup(3, [vol], 1)
        eps = 1e-8 * max(x1 - x0, y1 - y0, z1 - z0)
        _tag_curves_by_center(
            gmsh,
            2,
            {
                tags["bottom"]: lambda c: abs(c[2] - z0) < eps,
                tags["top"]: lambda c: abs(c[2] - z1) < eps,
                tags["sides"]: lambda c: True,
            },
        )
        field = gmsh.model.mesh.field
        f = field.add("MathEval")
        field.setString(f, "F", f"{h_bottom} + ({h_top} - {h_bottom}) * (z - ({z0})) / ({z1 - z0})")
        field.setAsBackgroundMesh(f)
        gmsh.option.setNumber("Mesh.MeshSizeExtendFromBoundary", 0)
        gmsh.option.setNumber("Mesh.MeshSizeFromPoints", 0)
        gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", 0)
        gmsh.model.mesh.generate(3)
        for _ in range(refinements):
            gmsh.model.mesh.refine()

    return build_on_root(comm, "box", 3, build)


def punch_block(
    comm: MPI.Comm,
    size: float,
    radius: float,
    h_rim: float,
    grading: float,
    tags: dict[str, int],
) -> MeshData:
    """A quarter block [0, L]² × [−L, 0] whose top face follows a punch's rim.

    The top face z = 0 is split along the quarter circle of radius a around the z
    axis, so mesh nodes lie on the rim where the pressure under a flat punch is
    singular. The element size is ``h_rim`` on the rim and grows linearly with the
    distance d from it, h = h_rim + ``grading`` d, up to L/4. Faces: ``"top"`` (both
    parts), ``"bottom"`` (z = −L), ``"sym_x"`` (x = 0), ``"sym_y"`` (y = 0) and
    ``"side"`` (x = L, y = L).

    Args:
        comm: Communicator.
        size: L.
        radius: The rim's radius a.
        h_rim: Element size on the rim.
        grading: Growth of the element size with the distance from the rim.
        tags: Tags of the faces named above.

    Returns:
        Mesh data.
    """
    check_lengths(size=size, radius=radius, h_rim=h_rim, grading=grading)
    if radius >= size:
        raise ValueError(f"The rim's radius {radius} must be less than the block's size {size}.")
    L, a = size, radius

    def build(gmsh):
        occ = gmsh.model.occ
        block = occ.addBox(0.0, 0.0, -L, L, L, L)
        disc = occ.addDisk(0.0, 0.0, 0.0, a, a)
        quarter = occ.addRectangle(0.0, 0.0, 0.0, a, a)
        cut, _ = occ.intersect([(2, disc)], [(2, quarter)])
        out, _ = occ.fragment([(3, block)], cut)
        occ.synchronize()
        volumes = [e for d, e in out if d == 3]
        gmsh.model.addPhysicalGroup(3, volumes, 1)
        eps = 1e-8 * L
        _tag_curves_by_center(
            gmsh,
            2,
            {
                tags["top"]: lambda c: abs(c[2]) < eps,
                tags["bottom"]: lambda c: abs(c[2] + L) < eps,
                tags["sym_x"]: lambda c: abs(c[0]) < eps,
                tags["sym_y"]: lambda c: abs(c[1]) < eps,
                tags["side"]: lambda c: True,
            },
        )
        # the one curved edge (OCC reports the arc as a circle or an ellipse)
        rim = [e for _, e in gmsh.model.getEntities(1) if gmsh.model.getType(1, e) != "Line"]
        if len(rim) != 1:
            raise RuntimeError(f"punch_block: expected one rim curve, found {len(rim)}.")
        field = gmsh.model.mesh.field
        dist = field.add("Distance")
        field.setNumbers(dist, "CurvesList", rim)
        field.setNumber(dist, "Sampling", max(100, int(4.0 * a / h_rim)))
        f = field.add("MathEval")
        field.setString(f, "F", f"Min({h_rim} + {grading} * F{dist}, {0.25 * L})")
        field.setAsBackgroundMesh(f)
        gmsh.option.setNumber("Mesh.MeshSizeExtendFromBoundary", 0)
        gmsh.option.setNumber("Mesh.MeshSizeFromPoints", 0)
        gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", 0)
        gmsh.model.mesh.generate(3)

    return build_on_root(comm, "punch_block", 3, build)


def lower_ball(
    comm: MPI.Comm,
    gdim: int,
    radius: float,
    h: float,
    h_contact: float,
    tags: dict[str, int],
    *,
    refine_radius: float,
    quarter: bool = False,
) -> MeshData:
    """The lower half of a disc (2D) or a ball (3D) of radius R centred at (0, …, R).

    The body touches the plane x_gdim = 0 at the origin. Boundary parts: ``"top"`` (the
    flat cut through the centre, x_gdim = R) and ``"surface"`` (the curved part); with
    ``quarter`` (3D: x ≥ 0, y ≥ 0; 2D: x ≥ 0) also the symmetry planes ``"sym_x"``
    (x = 0) and, in 3D, ``"sym_y"`` (y = 0).

    Args:
        comm: Communicator.
        gdim: 2 or 3.
        radius: R.
        h: Element size away from the contact zone.
        h_contact: Element size within ``refine_radius`` of the origin.
        tags: Tags of the parts named above.
        refine_radius: Where ``h_contact`` applies, growing to ``h`` at three times it.
        quarter: Keep the quarter (3D) or half (2D) that the symmetry planes cut off.

    Returns:
        Mesh data.
    """
    check_lengths(radius=radius, h=h, h_contact=h_contact, refine_radius=refine_radius)
    if gdim not in (2, 3):
        raise ValueError(f"gdim must be 2 or 3, got {gdim!r}.")
    R = radius
    low = 0.0 if quarter else -R

    def build(gmsh):
        occ = gmsh.model.occ
        if gdim == 2:
            ball = occ.addDisk(0.0, R, 0.0, R, R)
            cut = occ.addRectangle(low, 0.0, 0.0, R - low, R)
        else:
            ball = occ.addSphere(0.0, 0.0, R, R)
            cut = occ.addBox(low, low, 0.0, R - low, R - low, R)
        out, _ = occ.intersect([(gdim, ball)], [(gdim, cut)])
        occ.synchronize()
        gmsh.model.addPhysicalGroup(gdim, [e for _, e in out], 1)
        eps = 1e-8 * R
        rules = {tags["top"]: lambda c: abs(c[gdim - 1] - R) < eps}
        if quarter:
            rules[tags["sym_x"]] = lambda c: abs(c[0]) < eps
            if gdim == 3:
                rules[tags["sym_y"]] = lambda c: abs(c[1]) < eps
        rules[tags["surface"]] = lambda c: True
        _tag_curves_by_center(gmsh, gdim - 1, rules)
        lowest = [
            tag
            for _, tag in gmsh.model.getEntities(0)
            if np.linalg.norm(gmsh.model.getValue(0, tag, [])) < 1e-8 * R
        ]
        field = gmsh.model.mesh.field
        dist = field.add("Distance")
        if lowest:
            field.setNumbers(dist, "PointsList", lowest)
        else:  # the lowest point is inside a face: measure from the whole curved part
            surface = gmsh.model.getEntitiesForPhysicalGroup(gdim - 1, tags["surface"])
            field.setNumbers(dist, "SurfacesList" if gdim == 3 else "CurvesList", list(surface))
        thr = field.add("Threshold")
        field.setNumber(thr, "InField", dist)
        field.setNumber(thr, "DistMin", refine_radius)
        field.setNumber(thr, "DistMax", 3.0 * refine_radius + 4.0 * h)
        field.setNumber(thr, "SizeMin", h_contact)
        field.setNumber(thr, "SizeMax", h)
        if not lowest:
            # distance to the curved part is zero on all of it: refine by the height
            f = field.add("MathEval")
            axis = "y" if gdim == 2 else "z"
            field.setString(
                f,
                "F",
                f"{h_contact} + ({h} - {h_contact}) * Min(1, Max(0, ({axis} - "
                f"{0.5 * refine_radius**2 / R}) / ({3.0 * refine_radius}) ))",
            )
            field.setAsBackgroundMesh(f)
        else:
            field.setAsBackgroundMesh(thr)
        gmsh.option.setNumber("Mesh.MeshSizeExtendFromBoundary", 0)
        gmsh.option.setNumber("Mesh.MeshSizeFromPoints", 0)
        gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", 0)
        gmsh.model.mesh.generate(gdim)

    return build_on_root(comm, "lower_ball", gdim, build)
