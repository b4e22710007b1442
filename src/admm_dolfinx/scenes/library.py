"""Named contact scenes: the paper's examples, declared with only what they need.

A scene is the body's mesh with tagged boundary parts, a material, loads, Dirichlet
conditions and an analytic rigid obstacle (docs/design.md §6).  It knows nothing about
the solver: :meth:`Scene.problem` hands its data to
:class:`~admm_dolfinx.ContactProblem`, and from there the data flows one way.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
import ufl
from dolfinx import fem
from dolfinx.mesh import CellType, Mesh, MeshTags, create_box
from mpi4py import MPI

from admm_dolfinx.problem.contact_problem import ContactProblem
from admm_dolfinx.problem.obstacles import Ball, Obstacle, Plane
from admm_dolfinx.scenes.material import LinearElastic
from admm_dolfinx.scenes.meshing import (
    box,
    check_lengths,
    check_level,
    lower_ball,
    mesh_and_facet_tags,
    punch_block,
    quarter_disc,
    rectangle,
    structured_rectangle,
    tag_boundary,
)

__all__ = [
    "FLAT_PUNCH_TAGS",
    "SCENES",
    "FlatPunch",
    "Scene",
    "example1",
    "example2",
    "example3",
    "example3_hexahedral",
    "flat_punch",
    "flat_punch_graded",
    "flat_punch_on",
    "hertz",
    "hertz_solution",
    "hertz_sphere",
    "hertz_sphere_solution",
    "pressed_ball",
    "pressed_block",
]


@dataclass
class Scene:
    """A contact scene ready to become a :class:`~admm_dolfinx.ContactProblem`.

    Attributes:
        name: Short name (``"example1"``, ...).
        mesh: The body's mesh.
        facet_tags: Boundary tags; ``markers`` names them.
        markers: Name → tag value of the boundary parts.
        material: Linear elastic material.
        V: P1 vector displacement space.
        a: Elasticity bilinear form.
        L: Load linear form.
        bcs: Dirichlet conditions.
        contact_marker: Tag of Γ_C.
        obstacle: The rigid obstacle.
        h: Nominal mesh size.
        info: Free-form facts for reports (counts, parameters).
        surface: The body's true surface near Γ_C, as a map from points (k, gdim) to the
            nearest points on it, where the mesh's facets are chords of a curved body
            (for :func:`~admm_dolfinx.solve_adaptive`); None where the facets are it.
    """

    name: str
    mesh: Mesh
    facet_tags: MeshTags
    markers: dict[str, int]
    material: LinearElastic
    V: fem.FunctionSpace
    a: ufl.Form
    L: ufl.Form
    bcs: list[fem.DirichletBC]
    contact_marker: int
    obstacle: Obstacle
    h: float
    info: dict = field(default_factory=dict)
    surface: Callable[[np.ndarray], np.ndarray] | None = None

    def problem(self, **kwargs) -> ContactProblem:
        """Build the contact problem of this scene (kwargs go to ContactProblem)."""
        return ContactProblem(
            self.a,
            self.L,
            self.bcs,
            self.facet_tags,
            self.contact_marker,
            self.obstacle,
            **kwargs,
        )

    @property
    def num_nodes(self) -> int:
        """Global number of mesh nodes."""
        return self.mesh.geometry.index_map().size_global


#: The finest mesh size example1 builds (about 17 million cells: beyond what a
#: workstation factorises).
EXAMPLE1_FINEST_H = 1 / 2048


def example1(
    comm: MPI.Comm = MPI.COMM_WORLD,
    *,
    h: float = 1 / 8,
    mesher: str = "gmsh",
    E: float = 2000.0,
    nu: float = 0.3,
    traction: float = 10.0,
    gap: float = 0.01,
) -> Scene:
    """Example 1 of the paper: a rectangle pressed onto a rigid foundation.

    Ω = (0, 2) × (0, 1), plane strain, E = 2000, ν = 0.3. Clamped on Γ_D = {0} × (0, 1),
    a downward traction of 10 on the top side Γ_N = (0, 2) × {1}, candidate contact
    Γ_C = (0, 2) × {0} with a flat foundation at normalised gap 0.01 below it.

    Args:
        comm: Communicator.
        h: Mesh size, in [:data:`EXAMPLE1_FINEST_H`, 1].
        mesher: ``"gmsh"`` (unstructured, as in the paper) or ``"builtin"``
            (DOLFINx structured right-diagonal triangles, 2/h × 1/h squares).
        E: Young's modulus.
        nu: Poisson ratio.
        traction: Magnitude of the downward traction on the top side.
        gap: Distance from Γ_C to the foundation.

    Returns:
        The scene.
    """
    check_lengths(h=h)
    if not EXAMPLE1_FINEST_H <= h <= 1.0:
        raise ValueError(
            f"h must lie in [1/{round(1 / EXAMPLE1_FINEST_H)}, 1] for example1 (a 2 × 1 "
            f"rectangle: h = 1 is one cell across, h = 1/{round(1 / EXAMPLE1_FINEST_H)} "
            f"about {4 / EXAMPLE1_FINEST_H**2 / 1e6:.0f} million cells), got h = {h!r}. "
            "The paper's meshes go from h = 1/8 to 1/512."
        )
    tags = {"left": 1, "top": 2, "bottom": 3, "right": 4}
    if mesher == "gmsh":
        data = rectangle(comm, (0.0, 0.0), (2.0, 1.0), h, tags)
        msh, facet_tags = mesh_and_facet_tags(data)
    elif mesher == "builtin":
        n = round(1.0 / h)
        msh, facet_tags = structured_rectangle(comm, (0.0, 0.0), (2.0, 1.0), (2 * n, n), tags)
    else:
        raise ValueError(f"mesher must be 'gmsh' or 'builtin', got {mesher!r}.")
    material = LinearElastic(E, nu)
    V = fem.functionspace(msh, ("Lagrange", 1, (2,)))
    u, v = ufl.TrialFunction(V), ufl.TestFunction(V)
    ds = ufl.Measure("ds", domain=msh, subdomain_data=facet_tags)
    t = fem.Constant(msh, np.array([0.0, -traction]))
    clamp = fem.locate_dofs_topological(V, 1, facet_tags.find(tags["left"]))
    bcs = [fem.dirichletbc(np.zeros(2), clamp, V)]
    return Scene(
        name="example1",
        mesh=msh,
        facet_tags=facet_tags,
        markers=tags,
        material=material,
        V=V,
        a=material.bilinear_form(u, v),
        L=ufl.dot(t, v) * ds(tags["top"]),
        bcs=bcs,
        contact_marker=tags["bottom"],
        obstacle=Plane(point=(0.0, -gap), normal=(0.0, 1.0)),
        h=h,
        info={"E": E, "nu": nu, "traction": traction, "gap": gap, "mesher": mesher},
    )


def example2(
    comm: MPI.Comm = MPI.COMM_WORLD,
    *,
    level: int = 0,
    E: float = 2000.0,
    nu: float = 0.3,
    radius: float = 8.0,
    load: float = 1600.0,
    spring: float = 0.0,
) -> Scene:
    """Example 2 of the paper: the Hertz problem, a cylinder on a rigid foundation.

    The paper's text is not self-consistent (radius 8, yet Γ_C is written
    x1² + x2² = 16). This package reads it as follows: a cylinder of radius R = 8 rests
    on the plane y = 0, touching it at the origin; by symmetry only the quarter
    0 ≤ x ≤ R, 0 ≤ y ≤ R of the disc centred at (0, R) is modelled, with u_x = 0 on
    the symmetry line x = 0 (Γ_D), a uniform downward traction of total force
    ``load`` on the top side y = R (through the centre), and Γ_C the quarter arc.
    Nothing fixes the vertical motion: A is singular (a floating body) and only the
    contact holds the body, as in the paper.

    Args:
        comm: Communicator.
        level: Mesh level 0, 1, 2, ...: the arc gets 34·2^level elements, so the
            number of contact nodes is about 35, 69, 137, ... (the paper's meshes
            have 35, 69, 125, 229, 457).
        E: Young's modulus.
        nu: Poisson ratio.
        radius: R.
        load: Total downward force on the quarter's top side.
        spring: Stiffness per unit length of springs on the vertical motion of the
            symmetry line (the paper's "small positive constant on the vertical
            components of Γ_D"); 0 (the default) leaves the body floating.

    Returns:
        The scene.
    """
    level = check_level("level", level)
    tags = {"axis": 1, "top": 2, "arc": 3}
    arc = 0.5 * np.pi * radius
    h_contact = arc / (34 * 2**level)
    data = quarter_disc(comm, radius, 1.1 * h_contact, h_contact, tags)
    msh, facet_tags = mesh_and_facet_tags(data)
    material = LinearElastic(E, nu)
    V = fem.functionspace(msh, ("Lagrange", 1, (2,)))
    u, v = ufl.TrialFunction(V), ufl.TestFunction(V)
    ds = ufl.Measure("ds", domain=msh, subdomain_data=facet_tags)
    t = fem.Constant(msh, np.array([0.0, -load / radius]))
    axis = fem.locate_dofs_topological(V.sub(0), 1, facet_tags.find(tags["axis"]))
    bcs = [fem.dirichletbc(0.0, axis, V.sub(0))]
    a = material.bilinear_form(u, v)
    if spring > 0.0:
        a = a + spring * u[1] * v[1] * ds(tags["axis"])
    return Scene(
        name="example2",
        mesh=msh,
        facet_tags=facet_tags,
        markers=tags,
        material=material,
        V=V,
        a=a,
        L=ufl.dot(t, v) * ds(tags["top"]),
        bcs=bcs,
        contact_marker=tags["arc"],
        obstacle=Plane(point=(0.0, 0.0), normal=(0.0, 1.0)),
        h=h_contact,
        info={"E": E, "nu": nu, "radius": radius, "load": load, "level": level, "spring": spring},
    )


def _example3_ball() -> Ball:
    """Example 3's obstacle: the ball of radius 0.5 touching Γ_C at (−0.3, 0, −0.5)."""
    return Ball(center=(-0.3, 0.0, -1.0), radius=0.5)


def example3(
    comm: MPI.Comm = MPI.COMM_WORLD,
    *,
    level: int = 0,
    E: float = 1e6,
    nu: float = 0.45,
    displacement: float = 0.2,
    h_bottom: float = 0.3,
    h_top: float = 0.28,
) -> Scene:
    """Example 3 of the paper: a block pressed onto a rigid half-ball.

    Ω = (−0.5, 0.5) × (−1, 1) × (−0.5, 0.5), E = 10⁶, ν = 0.45. The top face is moved
    by u_D = (0, 0, −0.2); the bottom face z = −0.5 is Γ_C; the obstacle is the ball of
    radius 0.5 centred at (−0.3, 0, −1), which touches Γ_C at (−0.3, 0, −0.5).

    Args:
        comm: Communicator.
        level: 0 is a graded gmsh mesh of 198 nodes and 44 contact nodes (the
            paper's has 198/45); each level splits every tetrahedron into 8 (1121/151,
            7337/557, 52593/2137 nodes/contact nodes; the paper's: 1289/153, 9245/603,
            69897/2341). ``tests/scenes/test_library_counts.py`` checks these counts.
        E: Young's modulus.
        nu: Poisson ratio.
        displacement: Downward displacement of the top face.
        h_bottom: Element size of the level-0 mesh on Γ_C.
        h_top: Element size of the level-0 mesh on the top face.

    Returns:
        The scene.
    """
    level = check_level("level", level)
    return pressed_block(
        comm,
        name="example3",
        level=level,
        half_depth=0.5,
        h_bottom=h_bottom,
        h_top=h_top,
        displacement=displacement,
        obstacle=_example3_ball(),
        E=E,
        nu=nu,
    )


def pressed_block(
    comm: MPI.Comm,
    *,
    name: str,
    level: int,
    half_depth: float,
    h_bottom: float,
    h_top: float,
    displacement: float,
    obstacle: Obstacle,
    E: float = 1e6,
    nu: float = 0.45,
    clamp_sides: bool = False,
) -> Scene:
    """Example 3's block (−0.5, 0.5) × (−1, 1) × (−d, d), its top face moved down.

    The top face is moved by u_D = (0, 0, −displacement) (with ``clamp_sides`` the
    side faces too); the bottom face z = −d is Γ_C, above ``obstacle``.

    Args:
        comm: Communicator.
        name: The scene's name.
        level: Uniform refinements of the graded level-0 mesh.
        half_depth: d.
        h_bottom: Element size of the level-0 mesh on Γ_C.
        h_top: Element size of the level-0 mesh on the top face.
        displacement: Downward displacement of the top face.
        obstacle: The rigid obstacle under Γ_C.
        E: Young's modulus.
        nu: Poisson ratio.
        clamp_sides: Prescribe u_D on the side faces as well, so that Γ_C meets a
            Dirichlet boundary.

    Returns:
        The scene.
    """
    lower, upper = (-0.5, -1.0, -half_depth), (0.5, 1.0, half_depth)
    data = box(comm, lower, upper, h_bottom, h_top, level, _BLOCK_TAGS)
    msh, facet_tags = mesh_and_facet_tags(data)
    return _block_scene(
        name,
        msh,
        facet_tags,
        displacement=displacement,
        obstacle=obstacle,
        E=E,
        nu=nu,
        clamp_sides=clamp_sides,
        h=h_bottom / 2**level,
        info={"E": E, "nu": nu, "displacement": displacement, "level": level},
    )


#: Facet tags of the block scenes.
_BLOCK_TAGS = {"bottom": 3, "top": 1, "sides": 4}


def example3_hexahedral(
    comm: MPI.Comm = MPI.COMM_WORLD,
    *,
    cells: int = 12,
    E: float = 1e6,
    nu: float = 0.45,
    displacement: float = 0.2,
) -> Scene:
    """Example 3 on a structured hexahedral mesh (Q1): cells × 2 cells × cells boxes.

    The block, obstacle, material and load of :func:`example3`; a mesh of trilinear
    hexahedra (DOLFINx's built-in box) instead of gmsh's graded tetrahedra.

    Args:
        comm: Communicator.
        cells: Hexahedra across the block's width and height (twice as many along y).
        E: Young's modulus.
        nu: Poisson ratio.
        displacement: Downward displacement of the top face.

    Returns:
        The scene.
    """
    if isinstance(cells, bool) or not isinstance(cells, int | np.integer) or cells < 1:
        raise ValueError(f"cells must be a positive integer, got {cells!r}.")
    msh = create_box(
        comm,
        [np.array([-0.5, -1.0, -0.5]), np.array([0.5, 1.0, 0.5])],
        [int(cells), 2 * int(cells), int(cells)],
        CellType.hexahedron,
    )
    facet_tags = tag_boundary(
        msh,
        {
            _BLOCK_TAGS["bottom"]: lambda x: np.isclose(x[2], -0.5),
            _BLOCK_TAGS["top"]: lambda x: np.isclose(x[2], 0.5),
            _BLOCK_TAGS["sides"]: lambda x: np.full(x.shape[1], True),
        },
    )
    return _block_scene(
        "example3_hexahedral",
        msh,
        facet_tags,
        displacement=displacement,
        obstacle=_example3_ball(),
        E=E,
        nu=nu,
        clamp_sides=False,
        h=1.0 / cells,
        info={"E": E, "nu": nu, "displacement": displacement, "cells": cells},
    )


def _block_scene(
    name: str,
    msh: Mesh,
    facet_tags: MeshTags,
    *,
    displacement: float,
    obstacle: Obstacle,
    E: float,
    nu: float,
    clamp_sides: bool,
    h: float,
    info: dict,
) -> Scene:
    """The block's physics on a mesh tagged with :data:`_BLOCK_TAGS`."""
    tags = dict(_BLOCK_TAGS)
    material = LinearElastic(E, nu)
    V = fem.functionspace(msh, ("Lagrange", 1, (3,)))
    u, v = ufl.TrialFunction(V), ufl.TestFunction(V)
    zero = fem.Constant(msh, np.zeros(3))
    held = facet_tags.find(tags["top"])
    if clamp_sides:
        held = np.concatenate([held, facet_tags.find(tags["sides"])])
    dofs = fem.locate_dofs_topological(V, 2, held)
    bcs = [fem.dirichletbc(np.array([0.0, 0.0, -displacement]), dofs, V)]
    return Scene(
        name=name,
        mesh=msh,
        facet_tags=facet_tags,
        markers=tags,
        material=material,
        V=V,
        a=material.bilinear_form(u, v),
        L=ufl.dot(zero, v) * ufl.dx,
        bcs=bcs,
        contact_marker=tags["bottom"],
        obstacle=obstacle,
        h=h,
        info=info,
    )


def hertz_solution(load: float, radius: float, E: float, nu: float) -> tuple[float, float]:
    """Hertz's plane-strain solution for a cylinder on a rigid plane.

    A cylinder of radius R pressed by a force P per unit length onto a rigid flat
    touches it over |x| ≤ a with the pressure p(x) = p0 sqrt(1 − x²/a²), where
    a = sqrt(4PR / (π E*)), p0 = 2P / (π a) and E* = E / (1 − ν²).

    Args:
        load: P, force per unit length on the whole cylinder.
        radius: R.
        E: Young's modulus.
        nu: Poisson ratio.

    Returns:
        (a, p0).
    """
    e_star = E / (1.0 - nu**2)
    a = float(np.sqrt(4.0 * load * radius / (np.pi * e_star)))
    return a, 2.0 * load / (np.pi * a)


def sphere_surface(center: Sequence[float], radius: float) -> Callable[[np.ndarray], np.ndarray]:
    """The map of points to their nearest points on a circle (2D) or sphere (3D)."""
    c = np.asarray(center, dtype=np.float64)

    def project(x: np.ndarray) -> np.ndarray:
        d = np.asarray(x, dtype=np.float64) - c[: np.shape(x)[1]]
        length = np.linalg.norm(d, axis=1)
        return c[: np.shape(x)[1]] + radius * d / np.where(length > 0.0, length, 1.0)[:, None]

    return project


#: Facet tags of the Hertz cylinder.
HERTZ_TAGS = {"axis": 1, "top": 2, "arc": 3}


def hertz(
    comm: MPI.Comm = MPI.COMM_WORLD,
    *,
    level: int = 0,
    E: float = 2000.0,
    nu: float = 0.3,
    radius: float = 8.0,
    half_width: float = 0.6,
    h_contact: float | None = None,
    h_far: float = 0.6,
) -> Scene:
    """A cylinder on a rigid plane under a small load: Hertz's solution applies.

    The quarter cylinder of :func:`example2` with the load chosen so that the Hertz
    contact half-width is ``half_width`` (≤ R/10: small strains), and a mesh refined
    around the contact point: the element size there is a/4 / 2^level.

    Args:
        comm: Communicator.
        level: Refinement level (each halves the contact element size).
        E: Young's modulus.
        nu: Poisson ratio.
        radius: R.
        half_width: The Hertz half-width a that the load is chosen to produce.
        h_contact: The element size at the contact point (default a/4 / 2^level); the
            size ``h_far`` (or more) leaves the mesh uniform, for adaptive refinement.
        h_far: The element size away from the contact point.

    Returns:
        The scene; ``info`` holds the analytic ``a`` and ``p0``.
    """
    level = check_level("level", level)
    h_contact = h_contact if h_contact is not None else half_width / 4.0 / 2**level
    graded = h_contact < h_far
    data = quarter_disc(
        comm,
        radius,
        h_far,
        min(h_contact, h_far),
        HERTZ_TAGS,
        refine_radius=1.5 * half_width if graded else None,
    )
    msh, facet_tags = mesh_and_facet_tags(data)
    scene = hertz_on(msh, facet_tags, E=E, nu=nu, radius=radius, half_width=half_width)
    scene.h = min(h_contact, h_far)
    scene.info["level"] = level
    return scene


def hertz_on(
    msh: Mesh,
    facet_tags: MeshTags,
    *,
    E: float = 2000.0,
    nu: float = 0.3,
    radius: float = 8.0,
    half_width: float = 0.6,
) -> Scene:
    """The Hertz cylinder of :func:`hertz` on a given mesh of its quarter (tags ``HERTZ_TAGS``).

    What :func:`~admm_dolfinx.solve_adaptive` rebuilds on every refined mesh.
    """
    tags = HERTZ_TAGS
    e_star = E / (1.0 - nu**2)
    total = half_width**2 * np.pi * e_star / (4.0 * radius)  # P on the whole cylinder
    material = LinearElastic(E, nu)
    V = fem.functionspace(msh, ("Lagrange", 1, (2,)))
    u, v = ufl.TrialFunction(V), ufl.TestFunction(V)
    ds = ufl.Measure("ds", domain=msh, subdomain_data=facet_tags)
    t = fem.Constant(msh, np.array([0.0, -0.5 * total / radius]))  # half on the quarter
    axis = fem.locate_dofs_topological(V.sub(0), 1, facet_tags.find(tags["axis"]))
    a_exact, p0 = hertz_solution(total, radius, E, nu)
    return Scene(
        name="hertz",
        mesh=msh,
        facet_tags=facet_tags,
        markers=tags,
        material=material,
        V=V,
        a=material.bilinear_form(u, v),
        L=ufl.dot(t, v) * ds(tags["top"]),
        bcs=[fem.dirichletbc(0.0, axis, V.sub(0))],
        contact_marker=tags["arc"],
        obstacle=Plane(point=(0.0, 0.0), normal=(0.0, 1.0)),
        h=half_width / 4.0,
        info={
            "E": E,
            "nu": nu,
            "radius": radius,
            "load": total,
            "level": 0,
            "a": a_exact,
            "p0": p0,
        },
        surface=sphere_surface((0.0, radius), radius),
    )


def pressed_ball(
    comm: MPI.Comm = MPI.COMM_WORLD,
    *,
    gdim: int = 2,
    radius: float = 1.0,
    gap: float = 0.02,
    push: float = 0.08,
    h: float | None = None,
    h_contact: float | None = None,
    E: float = 1.0,
    nu: float = 0.3,
) -> Scene:
    """A half-disc (2D) or half-ball (3D) pressed far onto a rigid plane.

    The lower half of a disc or ball of radius R, centred at height R + ``gap`` above
    the plane x_gdim = 0; its flat top (through the centre) is moved down by ``push``,
    so that the contact zone spans a wide angle (``tests/problem/test_contact_model.py``
    presses it until the half-width exceeds R/3). The case that separates the two contact models
    (:mod:`admm_dolfinx.problem.obstacles`): along the body's normal, nodes far from the lowest
    point sink below the plane.

    Args:
        comm: Communicator.
        gdim: 2 or 3.
        radius: R.
        gap: Initial distance of the lowest point from the plane.
        push: Downward displacement of the flat top.
        h: Element size away from the contact zone (default R/8 in 2D, R/4 in 3D).
        h_contact: Element size in the contact zone (default R/40 in 2D, R/10 in 3D).
        E: Young's modulus.
        nu: Poisson ratio.

    Returns:
        The scene; ``info`` holds the expected half-width of the flattened zone.
    """
    check_lengths(radius=radius, push=push)
    h = h or radius / (8 if gdim == 2 else 4)
    h_contact = h_contact or radius / (40 if gdim == 2 else 10)
    tags = {"top": 1, "surface": 2}
    data = lower_ball(comm, gdim, radius, h, h_contact, tags, refine_radius=0.7 * radius)
    msh, facet_tags = mesh_and_facet_tags(data)
    msh.geometry.x[:, gdim - 1] += gap
    material = LinearElastic(E, nu)
    V = fem.functionspace(msh, ("Lagrange", 1, (gdim,)))
    u, v = ufl.TrialFunction(V), ufl.TestFunction(V)
    down = np.zeros(gdim)
    down[-1] = -push
    top = fem.locate_dofs_topological(V, gdim - 1, facet_tags.find(tags["top"]))
    normal = np.zeros(gdim)
    normal[-1] = 1.0
    overlap = push - gap
    return Scene(
        name="pressed_ball",
        mesh=msh,
        facet_tags=facet_tags,
        markers=tags,
        material=material,
        V=V,
        a=material.bilinear_form(u, v),
        L=ufl.dot(fem.Constant(msh, np.zeros(gdim)), v) * ufl.dx,
        bcs=[fem.dirichletbc(down, top, V)],
        contact_marker=tags["surface"],
        obstacle=Plane(point=np.zeros(gdim), normal=normal),
        h=h_contact,
        info={
            "E": E,
            "nu": nu,
            "radius": radius,
            "gap": gap,
            "push": push,
            "overlap half-width": float(np.sqrt(2.0 * radius * overlap - overlap**2)),
        },
    )


def hertz_sphere_solution(load: float, radius: float, E: float, nu: float) -> tuple[float, float]:
    """Hertz's solution for a sphere on a rigid plane: (a, p0) for a total force F.

    a = (3 F R / (4 E*))^{1/3}, p0 = 3 F / (2 π a²), E* = E / (1 − ν²); the pressure is
    p(r) = p0 sqrt(1 − r²/a²) on r ≤ a.
    """
    e_star = E / (1.0 - nu**2)
    a = float((3.0 * load * radius / (4.0 * e_star)) ** (1.0 / 3.0))
    return a, 3.0 * load / (2.0 * np.pi * a**2)


#: Facet tags of the Hertz sphere.
HERTZ_SPHERE_TAGS = {"top": 1, "surface": 2, "sym_x": 3, "sym_y": 4}


def hertz_sphere(
    comm: MPI.Comm = MPI.COMM_WORLD,
    *,
    level: int = 0,
    E: float = 1000.0,
    nu: float = 0.3,
    radius: float = 8.0,
    half_width: float = 0.4,
    h_far: float = 0.1,
    refine: float = 1.5,
    h_contact: float | None = None,
) -> Scene:
    """A sphere on a rigid plane under a small load (3D Hertz), by symmetry a quarter.

    The lower quarter-hemisphere (x ≥ 0, y ≥ 0) of a ball of radius R resting on the
    plane z = 0, with u_x = 0 on x = 0 and u_y = 0 on y = 0 and a uniform downward
    traction on its flat top chosen so that Hertz's contact radius is ``half_width``
    (R/20 by default: small strains, and a body large against the contact zone).
    Nothing holds the vertical motion but the contact (a floating body, like the
    paper's cylinder). The mesh is refined around the contact
    point: the element size there is a/3 / 2^level.

    Args:
        comm: Communicator.
        level: Refinement level (each halves the contact element size).
        E: Young's modulus.
        nu: Poisson ratio.
        radius: R.
        half_width: The Hertz contact radius a that the load is chosen to produce.
        h_far: Element size away from the contact zone, relative to R.
        refine: Radius of the refined zone around the contact point, relative to a.
        h_contact: The element size at the contact point (default a/3 / 2^level).

    Returns:
        The scene; ``info`` holds the analytic ``a``, ``p0`` and the total ``load`` F.
    """
    level = check_level("level", level)
    h_contact = h_contact if h_contact is not None else half_width / 3.0 / 2**level
    data = lower_ball(
        comm,
        3,
        radius,
        h_far * radius,
        min(h_contact, h_far * radius),
        HERTZ_SPHERE_TAGS,
        refine_radius=refine * half_width,
        quarter=True,
    )
    msh, facet_tags = mesh_and_facet_tags(data)
    scene = hertz_sphere_on(msh, facet_tags, E=E, nu=nu, radius=radius, half_width=half_width)
    scene.h = min(h_contact, h_far * radius)
    scene.info["level"] = level
    return scene


def hertz_sphere_on(
    msh: Mesh,
    facet_tags: MeshTags,
    *,
    E: float = 1000.0,
    nu: float = 0.3,
    radius: float = 8.0,
    half_width: float = 0.4,
) -> Scene:
    """The Hertz sphere of :func:`hertz_sphere` on a given mesh (tags ``HERTZ_SPHERE_TAGS``).

    What :func:`~admm_dolfinx.solve_adaptive` rebuilds on every refined mesh.
    """
    tags = HERTZ_SPHERE_TAGS
    e_star = E / (1.0 - nu**2)
    total = 4.0 * e_star * half_width**3 / (3.0 * radius)  # F for a = half_width
    material = LinearElastic(E, nu)
    V = fem.functionspace(msh, ("Lagrange", 1, (3,)))
    u, v = ufl.TrialFunction(V), ufl.TestFunction(V)
    ds = ufl.Measure("ds", domain=msh, subdomain_data=facet_tags)
    # F/4 on the quarter's top face, over its discrete area (a polygon, not πR²/4)
    area = msh.comm.allreduce(
        fem.assemble_scalar(fem.form(fem.Constant(msh, 1.0) * ds(tags["top"]))), op=MPI.SUM
    )
    t = fem.Constant(msh, np.array([0.0, 0.0, -0.25 * total / area]))
    bcs = [
        fem.dirichletbc(
            0.0, fem.locate_dofs_topological(V.sub(i), 2, facet_tags.find(tags[name])), V.sub(i)
        )
        for i, name in ((0, "sym_x"), (1, "sym_y"))
    ]
    a_exact, p0 = hertz_sphere_solution(total, radius, E, nu)
    return Scene(
        name="hertz_sphere",
        mesh=msh,
        facet_tags=facet_tags,
        markers=tags,
        material=material,
        V=V,
        a=material.bilinear_form(u, v),
        L=ufl.dot(t, v) * ds(tags["top"]),
        bcs=bcs,
        contact_marker=tags["surface"],
        obstacle=Plane(point=(0.0, 0.0, 0.0), normal=(0.0, 0.0, 1.0)),
        h=half_width / 3.0,
        info={
            "E": E,
            "nu": nu,
            "radius": radius,
            "load": total,
            "level": 0,
            "a": a_exact,
            "p0": p0,
            "quarter": True,
        },
        surface=sphere_surface((0.0, 0.0, radius), radius),
    )


class FlatPunch(Obstacle):
    """A rigid flat-ended circular punch pressed down into a body below it (3D).

    Its flat end is the disc of radius ``radius`` around the z axis at height
    ``-depth``; its normal points down, towards the body. A point of the body under
    the disc has the signed distance −(z + depth) (negative: inside the punch); a
    point outside the disc's radius can never touch it (+inf).

    Args:
        radius: The punch's radius a.
        depth: How far its end is pressed below z = 0, the body's free surface.
    """

    def __init__(self, radius: float, depth: float):
        check_lengths(radius=radius, depth=depth)
        self.radius, self.depth = float(radius), float(depth)

    def check_dimension(self, gdim: int) -> None:  # noqa: D102
        if gdim != 3:
            raise ValueError(f"FlatPunch is a 3D obstacle; the mesh is {gdim}D.")

    def signed_distance(self, x):  # noqa: D102
        x = np.asarray(x, dtype=np.float64)
        # a mesh that follows the rim puts nodes on it to round-off: they are under it
        under = np.hypot(x[:, 0], x[:, 1]) <= self.radius * (1.0 + RIM_TOLERANCE)
        g = np.where(under, -(x[:, 2] + self.depth), np.inf)
        normal = np.zeros_like(x)
        normal[:, 2] = -1.0
        return g, normal

    def __repr__(self) -> str:
        return f"FlatPunch(radius={self.radius}, depth={self.depth})"


#: Points this far outside the punch's rim, relative to its radius, are under it.
RIM_TOLERANCE = 1e-12

#: Facet tags of the flat-punch block.
FLAT_PUNCH_TAGS = {"top": 1, "bottom": 2, "sym_x": 3, "sym_y": 4, "side": 5}


def flat_punch(
    comm: MPI.Comm = MPI.COMM_WORLD,
    *,
    radius: float = 1.0,
    depth: float = 1e-4,
    size: float = 1000.0,
    cells: int = 4,
    E: float = 1.0,
    nu: float = 0.3,
) -> Scene:
    """A rigid flat circular punch pressed into a large block: Boussinesq's solution applies.

    A quarter (x, y ≥ 0, symmetry conditions on x = 0 and y = 0) of the block
    [−L, L]² × [−L, 0] with its bottom fixed, under a :class:`FlatPunch` of radius a
    pressed ``depth`` = δ into its top. On a half-space the force is F = 2 a E* δ
    (E* = E/(1 − ν²)) and the pressure p(r) = F / (2π a sqrt(a² − r²)), infinite at the
    punch's edge: a case for the contact force, not the peak pressure. The block's
    size L (1000 a by default) makes the half-space's answer exact to well under 1 %,
    and so does the depth δ ≪ a: the surface just outside the rim moves inwards by
    O(δ), and where a node there lies closer than that to the rim the punch's side
    stops it, a contact Boussinesq's linear theory does not have; the mesh is a
    coarse uniform one (``cells`` per side) for :func:`~admm_dolfinx.solve_adaptive`
    to refine.

    Args:
        comm: Communicator.
        radius: The punch's radius a.
        depth: δ.
        size: L.
        cells: Tetrahedra boxes per side of the coarse mesh.
        E: Young's modulus.
        nu: Poisson ratio.

    Returns:
        The scene; ``info["force"]`` is Boussinesq's force on the quarter, F/4.
    """
    check_lengths(radius=radius, depth=depth, size=size)
    msh = create_box(
        comm, [[0.0, 0.0, -size], [size, size, 0.0]], [cells] * 3, CellType.tetrahedron
    )
    fdim = 2
    msh.topology.create_connectivity(fdim, 3)
    from dolfinx import mesh as dmesh

    boundary = dmesh.exterior_facet_indices(msh.topology)
    mid = dmesh.compute_midpoints(msh, fdim, boundary)
    tol = 1e-9 * size
    values = np.full(boundary.size, FLAT_PUNCH_TAGS["side"], dtype=np.int32)
    values[np.abs(mid[:, 0]) < tol] = FLAT_PUNCH_TAGS["sym_x"]
    values[np.abs(mid[:, 1]) < tol] = FLAT_PUNCH_TAGS["sym_y"]
    values[np.abs(mid[:, 2] + size) < tol] = FLAT_PUNCH_TAGS["bottom"]
    values[np.abs(mid[:, 2]) < tol] = FLAT_PUNCH_TAGS["top"]
    tags = dmesh.meshtags(msh, fdim, boundary.astype(np.int32), values)
    return flat_punch_on(msh, tags, radius=radius, depth=depth, E=E, nu=nu)


def flat_punch_graded(
    comm: MPI.Comm = MPI.COMM_WORLD,
    *,
    level: int = 0,
    radius: float = 1.0,
    depth: float = 1e-4,
    size: float = 1000.0,
    grading: float = 0.3,
    E: float = 1.0,
    nu: float = 0.3,
) -> Scene:
    """The flat punch of :func:`flat_punch` on a gmsh mesh graded by hand towards its rim.

    The mesh follows the rim (nodes on the circle r = a, where the pressure is
    singular) with the element size a/4 / 2^level there, growing linearly with the
    distance from the rim at the rate ``grading`` / 2^level (both halve per level,
    so the whole mesh is finer on every level, not only the rim).

    Args:
        comm: Communicator.
        level: Refinement level.
        radius: The punch's radius a.
        depth: δ.
        size: L.
        grading: The size's growth with the distance from the rim on level 0.
        E: Young's modulus.
        nu: Poisson ratio.

    Returns:
        The scene, with ``info`` as :func:`flat_punch` gives it.
    """
    level = check_level("level", level)
    check_lengths(radius=radius, depth=depth, size=size, grading=grading)
    h_rim = 0.25 * radius / 2**level
    data = punch_block(comm, size, radius, h_rim, grading / 2**level, FLAT_PUNCH_TAGS)
    msh, tags = mesh_and_facet_tags(data)
    scene = flat_punch_on(msh, tags, radius=radius, depth=depth, E=E, nu=nu)
    scene.h = h_rim
    scene.info["level"] = level
    return scene


def flat_punch_on(
    msh: Mesh,
    facet_tags: MeshTags,
    *,
    radius: float = 1.0,
    depth: float = 1e-4,
    E: float = 1.0,
    nu: float = 0.3,
) -> Scene:
    """The flat punch of :func:`flat_punch` on a given mesh (tags ``FLAT_PUNCH_TAGS``).

    What :func:`~admm_dolfinx.solve_adaptive` rebuilds on every refined mesh.
    """
    tags = FLAT_PUNCH_TAGS
    material = LinearElastic(E, nu)
    V = fem.functionspace(msh, ("Lagrange", 1, (3,)))
    u, v = ufl.TrialFunction(V), ufl.TestFunction(V)
    bcs = [
        fem.dirichletbc(
            0.0, fem.locate_dofs_topological(V.sub(i), 2, facet_tags.find(tags[name])), V.sub(i)
        )
        for i, name in ((0, "sym_x"), (1, "sym_y"))
    ]
    bottom = fem.locate_dofs_topological(V, 2, facet_tags.find(tags["bottom"]))
    bcs.append(fem.dirichletbc(fem.Constant(msh, np.zeros(3)), bottom, V))
    e_star = E / (1.0 - nu**2)
    return Scene(
        name="flat_punch",
        mesh=msh,
        facet_tags=facet_tags,
        markers=tags,
        material=material,
        V=V,
        a=material.bilinear_form(u, v),
        L=ufl.dot(fem.Constant(msh, np.zeros(3)), v) * ufl.dx,
        bcs=bcs,
        contact_marker=tags["top"],
        obstacle=FlatPunch(radius, depth),
        h=radius,
        info={
            "E": E,
            "nu": nu,
            "a": radius,
            "depth": depth,
            "force": 0.25 * 2.0 * radius * e_star * depth,
            "area": 0.25 * np.pi * radius**2,
            "quarter": True,
        },
    )


#: Scene builders by name.
SCENES = {
    "example1": example1,
    "example2": example2,
    "example3": example3,
    "hertz": hertz,
    "hertz_sphere": hertz_sphere,
}
