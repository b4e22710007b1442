"""An under-resolved contact zone is said so, with an estimate of the peak pressure's error.

A half-disc pressed onto a plane: at h = 0.08 one node carries the contact and its
pressure is 16 % below the peak that a fine mesh gives (35 % at h = 0.12); nothing
warned. Now the result says so, with an estimate from the gaps at the nearest free
nodes (:mod:`admm_dolfinx.problem.resolution`), and stays silent on the package's
well-resolved scenes.
"""

from __future__ import annotations

import numpy as np
import pytest
import ufl
from dolfinx import fem, mesh
from mpi4py import MPI

from admm_dolfinx import ADMMSolver, Ball, ContactProblem
from admm_dolfinx.problem.resolution import (
    half_width_from_separation,
    patch_mean,
    separation_ratio,
)
from admm_dolfinx.scenes import library
from admm_dolfinx.scenes.material import LinearElastic

pytestmark = pytest.mark.timeout(300)
COMM = MPI.COMM_WORLD
PUSH = 0.0235  # a Hertzian zone of half-width 0.0425 on the unit half-disc


def _solve(scene):
    problem = scene.problem()
    with ADMMSolver(problem) as solver:
        return solver.solve()


@pytest.fixture(scope="module")
def fine_peak():
    """The half-disc's peak pressure on a mesh of h = 0.004 at the contact."""
    scene = library.pressed_ball(COMM, gdim=2, h=0.05, h_contact=0.004, push=PUSH)
    return _solve(scene).max_pressure


@pytest.mark.parametrize("h", [0.12, 0.08])
def test_an_under_resolved_half_disc_is_said_so_with_the_error(h, fine_peak):
    result = _solve(library.pressed_ball(COMM, gdim=2, h=h, h_contact=h, push=PUSH))
    true_error = result.max_pressure / fine_peak - 1.0
    assert true_error < -0.1  # the computed peak is far below
    resolution = result.resolution
    assert resolution is not None and not resolution.resolved
    assert resolution.active_near_peak == 1
    # the estimate: the right sign, within a factor 1.5 of the true error
    assert resolution.peak_error is not None
    assert true_error / 1.5 > resolution.peak_error > true_error * 1.5
    # and the zone's half-width from the gaps: within 10 % of the fine mesh's
    assert resolution.half_width == pytest.approx(0.0425, rel=0.1)
    text = result.warning
    assert "under-resolved" in text and "solve_adaptive" in text and "Refine" in text
    assert f"{abs(resolution.peak_error):.0%}" in text
    assert "UNDER-RESOLVED" in result.summary()


@pytest.mark.parametrize("depth", [0.01, 0.03], ids=["no-node-touches", "nodes-touch"])
def test_a_coarse_3d_contact_face_on_a_ball_is_said_so(depth):
    """A block with a coarse bottom pressed onto a ball (as a part onto a bearing ball):
    the ball enters the coarse facets between their nodes, whether or not a node
    touches it."""
    cell = mesh.CellType.tetrahedron
    msh = mesh.create_box(COMM, [[0.0, 0.0, 0.0], [1.0, 1.0, 0.5]], [3, 3, 3], cell)
    bottom = mesh.locate_entities_boundary(msh, 2, lambda x: np.isclose(x[2], 0.0))
    top = mesh.locate_entities_boundary(msh, 2, lambda x: np.isclose(x[2], 0.5))
    facets = np.concatenate([bottom, top])
    values = np.concatenate([np.full(bottom.size, 1), np.full(top.size, 2)]).astype(np.int32)
    order = np.argsort(facets)
    tags = mesh.meshtags(msh, 2, facets[order], values[order])
    V = fem.functionspace(msh, ("Lagrange", 1, (3,)))
    u, v = ufl.TrialFunction(V), ufl.TestFunction(V)
    L = ufl.dot(fem.Constant(msh, np.zeros(3)), v) * ufl.dx
    push = fem.dirichletbc(
        np.array([0.0, 0.0, -depth]), fem.locate_dofs_topological(V, 2, tags.find(2)), V
    )
    ball = Ball((0.45, 0.52, -2.0), 1.995)  # its top 0.005 below the face, off the nodes
    material = LinearElastic(2000.0, 0.3)
    problem = ContactProblem(material.bilinear_form(u, v), L, [push], tags, 1, ball)
    with ADMMSolver(problem) as solver:
        result = solver.solve()
    assert result.converged and not result.resolution.resolved
    assert "between contact nodes" in result.warning and "under-resolved" in result.warning


@pytest.mark.parametrize(
    "scene",
    [
        lambda: library.example1(COMM, h=1 / 32),
        lambda: library.example2(COMM, level=0),
        lambda: library.example3(COMM, level=2),
        lambda: library.hertz(COMM, level=0),
        lambda: library.hertz_sphere(COMM, level=0),
        lambda: library.pressed_ball(COMM, gdim=2),
        lambda: library.pressed_ball(COMM, gdim=3),
    ],
    ids=["example1", "example2", "example3-L2", "hertz", "hertz_sphere", "disc", "ball"],
)
def test_silent_on_the_packages_resolved_scenes(scene):
    result = _solve(scene())
    assert result.resolution.resolved and "under-resolved" not in result.warning


def test_the_hertzian_formulas():
    """The separation ratio rises from 0 at the zone's edge to 1 far away, and the
    half-width it gives back is the one it came from; a patch wider than the zone
    has the mean p0 π a / (4 r) (2D) and 2 p0 a² / (3 r²) (3D)."""
    for gdim in (2, 3):
        assert separation_ratio(1.0, gdim) == 0.0
        assert 0.99 < separation_ratio(1e3, gdim) < 1.0
        for rho in (1.05, 1.5, 3.0):
            ratio = separation_ratio(rho, gdim)
            assert half_width_from_separation(0.3, ratio, gdim) == pytest.approx(0.3 / rho)
        assert half_width_from_separation(0.3, 1.2, gdim) is None
        assert patch_mean(1e-6, gdim) == pytest.approx(1.0)
    assert patch_mean(2.0, 2) == pytest.approx(np.pi / 8)
    assert patch_mean(2.0, 3) == pytest.approx(2.0 / 12)
