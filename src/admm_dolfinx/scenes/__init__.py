"""Contact scenes: the paper's examples, validation and hard cases, meshed with gmsh.

A scene declares only what its physics needs and knows nothing about the solver;
:meth:`Scene.problem` hands its data to :class:`~admm_dolfinx.ContactProblem`.
"""

from admm_dolfinx.scenes.library import (
    SCENES,
    Scene,
    example1,
    example2,
    example3,
    example3_hexahedral,
    hertz,
    hertz_solution,
    hertz_sphere,
    hertz_sphere_solution,
    pressed_ball,
    pressed_block,
)

__all__ = [
    "SCENES",
    "Scene",
    "example1",
    "example2",
    "example3",
    "example3_hexahedral",
    "hertz",
    "hertz_solution",
    "hertz_sphere",
    "hertz_sphere_solution",
    "pressed_ball",
    "pressed_block",
]
