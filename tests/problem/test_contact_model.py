"""The contact model: non-penetration along the obstacle's normal (default) or the body's.

A curved body pressed far onto a rigid plane (contact half-width > R/3) is the case
that separates the two: along the obstacle's normal no node ends below the plane and
the answer matches SNES VI with bounds on the same discrete problem; along the body's
normal (the paper's model) nodes sink and the contact force is lower. Curved and
tilted obstacles are checked against OSQP on the extracted QP. Serially and under
``mpiexec -n 2``.
"""

from __future__ import annotations

import numpy as np
import pytest
from mpi4py import MPI

from admm_dolfinx import ADMMSolver, Ball, ContactProblem, Obstacle, Plane
from admm_dolfinx.problem.forces import contact_force, reaction_force
from admm_dolfinx.scenes.library import example1, pressed_ball
from admm_dolfinx.studies.baselines import solve_osqp, solve_snes_vi

from conftest import gather_nodal, rel_diff

pytestmark = pytest.mark.timeout(300)
COMM = MPI.COMM_WORLD
PUSH = 0.15  # 7.5 gaps: the contact zone's half-width exceeds R/3


@pytest.fixture(scope="module", params=[2, 3], ids=["disc", "ball"])
def scene(request):
    return pressed_ball(COMM, gdim=request.param, push=PUSH)


def _lowest(problem, result) -> float:
    c = problem.contact
    bs = problem.V.dofmap.index_map_bs
    height = c.coordinates[:, -1] + result.u.x.array.reshape(-1, bs)[c.nodes, problem.gdim - 1]
    return float(COMM.allreduce(float(height.min(initial=np.inf)), op=MPI.MIN))


def _half_width(problem, result) -> float:
    c = problem.contact
    radial = np.linalg.norm(c.coordinates[:, :-1], axis=1)[result.multiplier > 0]
    return float(COMM.allreduce(float(radial.max(initial=0.0)), op=MPI.MAX))


def test_curved_body_stays_out_of_the_plane(scene):
    problem = scene.problem()
    assert problem.contact_normal == "obstacle"
    with ADMMSolver(problem, rtol=1e-10) as solver:
        result = solver.solve()
    assert result.converged
    assert _half_width(problem, result) > scene.info["radius"] / 3
    # no node below the plane
    assert _lowest(problem, result) >= -1e-9 * scene.info["gap"]
    # the same discrete problem by SNES VI (vertical bounds)
    reference = solve_snes_vi(problem)
    assert rel_diff(gather_nodal(result.u)[1], gather_nodal(reference.u)[1]) <= 1e-6
    # the contact force balances the reaction of the pushed top face
    force = contact_force(problem, result.multiplier)
    reaction = reaction_force(problem, result.u, scene.markers["top"], result.multiplier)
    assert np.linalg.norm(force + reaction) <= 1e-6 * np.linalg.norm(force)
    assert force[-1] > 0.0  # the plane pushes the body up
    problem.destroy()


def test_the_papers_model_lets_the_body_sink(scene):
    """What the model choice changes: along the body's normal, nodes far from the
    lowest point end below the plane and the force comes out lower."""
    exact = scene.problem()
    paper = scene.problem(contact_normal="body")
    forces = []
    for problem in (exact, paper):
        with ADMMSolver(problem, rtol=1e-10) as solver:
            result = solver.solve()
        forces.append(contact_force(problem, result.multiplier)[-1])
        lowest = _lowest(problem, result)
    assert lowest < -0.1 * scene.info["gap"]  # the paper's model: below the plane
    assert forces[1] < 0.95 * forces[0]
    exact.destroy()
    paper.destroy()


def _serial_twin(scene_builder, obstacle, model="obstacle"):
    twin = scene_builder(MPI.COMM_SELF)
    return ContactProblem(
        twin.a,
        twin.L,
        twin.bcs,
        twin.facet_tags,
        twin.contact_marker,
        obstacle,
        contact_normal=model,
    )


@pytest.mark.parametrize(
    "obstacle",
    [
        Plane((0.0, -0.01), (np.sin(0.3), np.cos(0.3))),  # tilted
        Ball((0.4, -1.0), 1.0),  # curved, off-centre
    ],
    ids=["tilted-plane", "ball"],
)
def test_tilted_and_curved_obstacles_against_osqp(obstacle):
    """2D half-disc on a tilted plane and on a ball: the ADMM (all ranks) against OSQP at
    a tight tolerance on the same discrete QP (one process)."""

    def build(comm):
        return pressed_ball(comm, gdim=2, push=0.1)

    scene = build(COMM)
    problem = ContactProblem(
        scene.a, scene.L, scene.bcs, scene.facet_tags, scene.contact_marker, obstacle
    )
    with ADMMSolver(problem, rtol=1e-10) as solver:
        result = solver.solve()
    assert result.converged and result.num_active > 3
    reference = solve_osqp(_serial_twin(build, obstacle))
    assert reference.kkt.max() <= 1e-6
    assert rel_diff(gather_nodal(result.u)[1], gather_nodal(reference.u)[1]) <= 1e-5


def test_moved_ball_turns_the_normals_and_the_solver_follows():
    """update_obstacle with a moved ball: the contact directions turn, N changes, and
    the next solve rebuilds r* and the factors; it equals a fresh problem's solve."""
    scene = pressed_ball(COMM, gdim=2, push=0.05)
    problem = ContactProblem(
        scene.a, scene.L, scene.bcs, scene.facet_tags, scene.contact_marker, Ball((0.0, -1.0), 1.0)
    )
    with ADMMSolver(problem, rtol=1e-10) as solver:
        solver.solve()
        moved = Ball((0.3, -1.0), 1.0)
        problem.update_obstacle(moved)
        assert problem.operator_version == 1
        result = solver.solve()
    fresh = ContactProblem(
        scene.a, scene.L, scene.bcs, scene.facet_tags, scene.contact_marker, moved
    )
    with ADMMSolver(fresh, rtol=1e-10) as solver:
        expected = solver.solve()
    assert rel_diff(gather_nodal(result.u)[1], gather_nodal(expected.u)[1]) <= 1e-9
    # a plane moved without turning keeps N (and the factors)
    flat = example1(COMM, h=1 / 8, mesher="builtin").problem()
    flat.update_obstacle(Plane((0.0, -0.02), (0.0, 1.0)))
    assert flat.operator_version == 0


def test_obstacle_geometry_is_exact():
    plane = Plane((0.0, 1.0, 0.0), (0.0, 2.0, 0.0))
    x = np.array([[0.3, 1.5, 2.0], [0.0, 0.5, 0.0]])
    g, nu = plane.signed_distance(x)
    np.testing.assert_allclose(g, [0.5, -0.5])
    np.testing.assert_allclose(nu, [[0.0, 1.0, 0.0]] * 2)
    ball = Ball((0.0, 0.0), 2.0)
    g, nu = ball.signed_distance(np.array([[3.0, 4.0], [0.0, 1.0]]))
    np.testing.assert_allclose(g, [3.0, -1.0])
    np.testing.assert_allclose(nu, [[0.6, 0.8], [0.0, 1.0]])


class RayOnly(Obstacle):
    """A user obstacle that knows only the gap along a ray (the old interface)."""

    def gap(self, x, n):
        return Plane((0.0, -0.01), (0.0, 1.0)).gap(x, n)


class DistanceOnly(Obstacle):
    """A user obstacle with the signed distance only: nodes right of x = 1 never touch."""

    def signed_distance(self, x):
        g, nu = Plane((0.0, -0.01), (0.0, 1.0)).signed_distance(x)
        return np.where(x[:, 0] > 1.0, np.inf, g), nu


def _with(obstacle, model="obstacle"):
    scene = example1(COMM, h=1 / 8, mesher="builtin")
    return ContactProblem(
        scene.a,
        scene.L,
        scene.bcs,
        scene.facet_tags,
        scene.contact_marker,
        obstacle,
        contact_normal=model,
    )


def test_user_obstacles_of_either_interface():
    with pytest.raises(ValueError, match="contact_normal='body'"):
        _with(RayOnly())
    ray = ADMMSolver(_with(RayOnly(), "body")).solve()
    assert ray.converged
    problem = _with(DistanceOnly())
    c = problem.contact
    assert np.all(np.isinf(c.gap[c.coordinates[:, 0] > 1.0]))  # never touch: +inf
    result = ADMMSolver(problem).solve()
    assert result.converged
    assert np.all(result.multiplier[c.coordinates[:, 0] > 1.0] == 0.0)
    with pytest.raises(ValueError, match="contact_normal='obstacle'"):
        _with(DistanceOnly(), "body")


def test_node_behind_a_plane_in_the_papers_model_is_explained():
    """A node behind the plane whose normal points away: the paper's model cannot push
    it out (once a silent +inf); the default model gives it a negative gap."""
    behind = Plane((0.0, -0.5), (0.0, -1.0))  # the obstacle is y > -0.5: Γ_C inside it
    with pytest.raises(ValueError, match="cannot push them out"):
        _with(behind, "body")
    problem = _with(Plane((0.0, 0.005), (0.0, 1.0)))  # the bottom starts 0.005 inside
    assert np.allclose(problem.contact.gap, -0.005)
