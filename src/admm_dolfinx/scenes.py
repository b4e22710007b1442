"""Named contact scenes: the paper's examples, declared with only what they need.

A scene is the body's mesh with tagged boundary parts, a material, loads, Dirichlet
conditions and an analytic rigid obstacle (design.md §5).  It knows nothing about
the solver: :meth:`Scene.problem` hands its data to
:class:`~admm_dolfinx.ContactProblem`, and from there the data flows one way.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import ufl
from dolfinx import fem, mesh
from mpi4py import MPI

from admm_dolfinx.material import LinearElastic
from admm_dolfinx.meshing import rectangle, structured_rectangle
from admm_dolfinx.obstacles import Obstacle, Plane
from admm_dolfinx.problem import ContactProblem

__all__ = ["Scene", "example1"]


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
    """

    name: str
    mesh: mesh.Mesh
    facet_tags: mesh.MeshTags
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

    def problem(self, **kwargs) -> ContactProblem:
        """Build the contact problem of this scene (kwargs go to ContactProblem)."""
        return ContactProblem(
            self.a, self.L, self.bcs, self.facet_tags, self.contact_marker, self.obstacle,
            **kwargs,
        )

    @property
    def num_nodes(self) -> int:
        """Global number of mesh nodes."""
        return self.mesh.geometry.index_map().size_global


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
        h: Mesh size.
        mesher: ``"gmsh"`` (unstructured, as in the paper) or ``"builtin"``
            (DOLFINx structured right-diagonal triangles, 2/h × 1/h squares).
        E: Young's modulus.
        nu: Poisson ratio.
        traction: Magnitude of the downward traction on the top side.
        gap: Distance from Γ_C to the foundation.

    Returns:
        The scene.
    """
    tags = {"left": 1, "top": 2, "bottom": 3, "right": 4}
    if mesher == "gmsh":
        data = rectangle(comm, (0.0, 0.0), (2.0, 1.0), h, tags)
        msh, facet_tags = data.mesh, data.facet_tags
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
