"""Hard cases for the stability suite.

Nearly incompressible material, extreme scales, gaps and loads, graded and distorted
meshes, a floating body, and in 3D a curved obstacle, ν = 0.499, no contact, the
whole face in contact and an initial penetration; each is a
:class:`~admm_dolfinx.scenes.library.Scene`.

Used by ``tests/scenes/test_hard_cases.py`` (small sizes) and ``benchmarks/hard_cases.py``
(the README's iteration table).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np
import ufl
from dolfinx import fem, mesh
from mpi4py import MPI

from admm_dolfinx.problem.contact_set import mesh_bounds
from admm_dolfinx.problem.obstacles import Obstacle, Plane
from admm_dolfinx.scenes.library import Scene, example1, example2, example3
from admm_dolfinx.scenes.material import LinearElastic

__all__ = ["CASES", "build_case", "distort", "grade", "strip"]


def strip(
    comm: MPI.Comm = MPI.COMM_WORLD,
    *,
    cells: int = 1000,
    length: float = 20.0,
    thickness: float = 0.1,
    layers: int = 10,
    E: float = 1.0,
    nu: float = 0.3,
    pressure: float = 1e-3,
    gap: float = 1e-3,
) -> Scene:
    """A long thin strip, clamped at its left end, pressed onto a rigid plane below.

    (0, length) × (0, thickness) in plane strain, ``cells`` × ``layers`` squares of
    right-diagonal triangles (DOLFINx's builtin mesh, no gmsh). A uniform pressure on
    the top side pushes the strip down by more than the gap, so that it lies on the
    plane except near the clamp. The strip bends like a beam: its smoothest contact
    mode is orders of magnitude more compliant than its roughest (``python
    benchmarks/strips.py`` prints κ of the contact pencil), which is what broke the
    dense r* and needs active-set polishing to converge.
    Γ_C = the bottom side, with ``cells`` contact nodes (the clamped corner aside).
    """
    tags = {"bottom": 1, "top": 2, "left": 3}
    msh = mesh.create_rectangle(comm, [[0.0, 0.0], [length, thickness]], [cells, layers])
    fdim = 1
    msh.topology.create_connectivity(fdim, 2)
    found = {
        name: mesh.locate_entities_boundary(msh, fdim, where)
        for name, where in (
            ("bottom", lambda x: np.isclose(x[1], 0.0)),
            ("top", lambda x: np.isclose(x[1], thickness)),
            ("left", lambda x: np.isclose(x[0], 0.0)),
        )
    }
    facets = np.concatenate(list(found.values()))
    values = np.concatenate([np.full(f.size, tags[k]) for k, f in found.items()])
    facets, first = np.unique(facets, return_index=True)
    facet_tags = mesh.meshtags(msh, fdim, facets.astype(np.int32), values[first].astype(np.int32))
    material = LinearElastic(E, nu)
    V = fem.functionspace(msh, ("Lagrange", 1, (2,)))
    u, v = ufl.TrialFunction(V), ufl.TestFunction(V)
    ds = ufl.Measure("ds", domain=msh, subdomain_data=facet_tags)
    t = fem.Constant(msh, np.array([0.0, -pressure]))
    clamp = fem.locate_dofs_topological(V, fdim, facet_tags.find(tags["left"]))
    return Scene(
        name="strip",
        mesh=msh,
        facet_tags=facet_tags,
        markers=tags,
        material=material,
        V=V,
        a=material.bilinear_form(u, v),
        L=ufl.dot(t, v) * ds(tags["top"]),
        bcs=[fem.dirichletbc(np.zeros(2), clamp, V)],
        contact_marker=tags["bottom"],
        obstacle=Plane(point=(0.0, -gap), normal=(0.0, 1.0)),
        h=length / cells,
        info={"E": E, "nu": nu, "cells": cells, "length": length, "thickness": thickness},
    )


def grade(scene: Scene) -> Scene:
    """Grade the rectangle's mesh towards Γ_C and the clamp: x ↦ 2(x/2)^1.6, y ↦ y²."""
    x = scene.mesh.geometry.x
    x[:, 0] = 2.0 * (x[:, 0] / 2.0) ** 1.6
    x[:, 1] = x[:, 1] ** 2
    scene.info["mesh"] = "graded"
    return scene


def distort(scene: Scene, amount: float = 0.35) -> Scene:
    """Move interior nodes by up to ``amount``·h in a pseudo-random direction.

    The displacement is a deterministic function of the node's position, so ghost
    copies of a node move alike on every process. Boundary nodes stay put.
    """
    x = scene.mesh.geometry.x
    lo, hi = mesh_bounds(scene.mesh)[:, :2]
    interior = np.all((x[:, :2] > lo + 1e-12) & (x[:, :2] < hi - 1e-12), axis=1)
    phase = x[:, 0] * 12.9898 + x[:, 1] * 78.233
    angle = 2 * np.pi * ((np.sin(phase) * 43758.5453) % 1.0)
    radius = amount * scene.h * ((np.sin(phase * 1.7 + 1.0) * 24634.6345) % 1.0)
    x[interior, 0] += (radius * np.cos(angle))[interior]
    x[interior, 1] += (radius * np.sin(angle))[interior]
    scene.info["mesh"] = f"distorted ({amount} h)"
    return scene


def _e1(small: bool, **kwargs) -> Callable[[MPI.Comm], Scene]:
    return lambda comm: example1(comm, h=1 / 16 if small else 1 / 64, **kwargs)


def _builtin(small: bool, transform) -> Callable[[MPI.Comm], Scene]:
    return lambda comm: transform(example1(comm, h=1 / 16 if small else 1 / 64, mesher="builtin"))


def _e3(small: bool, obstacle: Obstacle | None = None, **kwargs) -> Callable[[MPI.Comm], Scene]:
    """Example 3 (levels 0 / 2), optionally with another obstacle (a flat punch)."""

    def build(comm: MPI.Comm) -> Scene:
        scene = example3(comm, level=0 if small else 2, **kwargs)
        return scene if obstacle is None else replace(scene, obstacle=obstacle)

    return build


def _cases(small: bool) -> dict[str, Callable[[MPI.Comm], Scene]]:
    return {
        "nu=0.49": _e1(small, nu=0.49),
        "nu=0.499": _e1(small, nu=0.499),
        "E=1": _e1(small, E=1.0, traction=10.0 / 2000.0),
        "E=1e9": _e1(small, E=1e9, traction=10.0 * 1e9 / 2000.0),
        "gap 0": _e1(small, gap=0.0),
        "negative gap": _e1(small, gap=-0.005),
        "nothing touches": _e1(small, gap=10.0),
        "all of Γ_C active": _e1(small, traction=1e4),
        "graded mesh": _builtin(small, grade),
        "distorted mesh": _builtin(small, distort),
        "floating body (Hertz)": lambda comm: example2(comm, level=0 if small else 2),
        "3D curved obstacle": _e3(small),
        "3D nu=0.499": _e3(small, nu=0.499),
        "3D nothing touches": _e3(small, displacement=-0.05),
        "3D all of Γ_C active": _e3(small, obstacle=Plane((0.0, 0.0, -0.52), (0.0, 0.0, 1.0))),
        "3D negative gap": _e3(
            small, displacement=0.0, obstacle=Plane((0.0, 0.0, -0.49), (0.0, 0.0, 1.0))
        ),
    }


#: Names of the hard cases.
CASES = tuple(_cases(True))


def build_case(name: str, comm: MPI.Comm = MPI.COMM_WORLD, *, small: bool = True) -> Scene:
    """Build the scene of a hard case.

    Args:
        name: One of :data:`CASES`.
        comm: Communicator.
        small: Fast sizes (tests) or larger ones (the benchmark table).

    Returns:
        The scene.
    """
    cases = _cases(small)
    if name not in cases:
        raise ValueError(f"unknown hard case {name!r}; choose one of {sorted(cases)}")
    return cases[name](comm)
