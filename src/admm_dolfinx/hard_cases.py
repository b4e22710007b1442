"""Hard cases for the stability suite.

Nearly incompressible material, extreme scales, gaps and loads, graded and distorted
meshes, a floating body, and in 3D a curved obstacle, ν = 0.499, no contact, the
whole face in contact and an initial penetration; each is a
:class:`~admm_dolfinx.scenes.Scene`.

Used by ``tests/test_hard_cases.py`` (small sizes) and ``benchmarks/hard_cases.py``
(the README's iteration table).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np
from mpi4py import MPI

from admm_dolfinx.meshing import global_bounds
from admm_dolfinx.obstacles import Obstacle, Plane
from admm_dolfinx.scenes import Scene, example1, example2, example3

__all__ = ["CASES", "build_case", "distort", "grade"]


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
    lo, hi = global_bounds(scene.mesh)[:, :2]
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
