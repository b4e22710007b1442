"""Boussinesq's flat punch on a mesh that follows its rim: nodes on the rim touch it.

The reference is analytic: on a half-space, a rigid flat circular punch pressed δ
deep carries F = 2 a E* δ (E* = E/(1 − ν²)); the block is 1000 a across, large enough
for that (``scenes.library.flat_punch``).
"""

from __future__ import annotations

import numpy as np
import pytest
from mpi4py import MPI

import admm_dolfinx as ad
from admm_dolfinx.scenes import library as lib

pytestmark = pytest.mark.timeout(300)


def test_a_point_on_the_rim_to_round_off_is_under_the_punch():
    punch = lib.FlatPunch(radius=1.0, depth=0.01)
    angle = np.pi / 7.0
    on_rim = np.array([[np.cos(angle), np.sin(angle), 0.0]])  # r = 1 to round-off
    outside = np.array([[1.0 + 1e-15, 0.0, 0.0], [1.0 + 1e-6, 0.0, 0.0]])
    g, normal = punch.signed_distance(np.vstack([on_rim, outside]))
    assert np.allclose(g[:2], -0.01) and np.isinf(g[2])
    assert np.allclose(normal[:, 2], -1.0)


def _solve(level):
    scene = lib.flat_punch_graded(MPI.COMM_WORLD, level=level)
    problem = scene.problem()
    with ad.ADMMSolver(problem) as solver:
        result = solver.solve()
    assert result.converged
    # the nodes on the rim, and whether the solution presses them (λ > 0)
    space = result.pressure.function_space
    owned = space.dofmap.index_map.size_local
    x = space.tabulate_dof_coordinates()[:owned]
    rim = (np.abs(np.hypot(x[:, 0], x[:, 1]) - 1.0) < 1e-12) & (np.abs(x[:, 2]) < 1e-12)
    pressed = result.pressure.x.array[:owned] > 0.0
    comm = problem.mesh.comm
    on_rim = comm.allreduce(int(rim.sum()))
    rim_active = comm.allreduce(int((rim & pressed).sum()))
    force = float(np.linalg.norm(result.contact_force))
    error = force / scene.info["force"] - 1.0
    problem.destroy()
    return on_rim, rim_active, error


def test_the_rim_following_mesh_converges_to_boussinesq():
    errors, rims = [], []
    for level in (0, 1):
        on_rim, rim_active, error = _solve(level)
        assert rim_active == on_rim  # every node on the rim touches the punch
        errors.append(error)
        rims.append(on_rim)
    assert 5 <= rims[0] < rims[1]  # the quarter rim carries nodes, more on the finer mesh
    # a P1 mesh is stiff: the force is too large, less so on the finer mesh
    assert 0.0 < errors[1] < errors[0] < 0.3
    assert errors[1] < 0.6 * errors[0]


@pytest.mark.parametrize("depth", [1e-4, 1e-2])
def test_the_strain_energy_is_the_work_of_the_contact_force(depth):
    """a(u_h, u_h) = F_h δ: the premise of the contact force's error estimate.

    With no loads and the punch's face at the depth δ, the discrete equilibrium tested
    with u_h gives a(u_h, u_h) = Σ λ_i u_h,n(x_i) over the contact nodes, and every
    pressed node sits at u_n = δ (complementarity): the energy is the contact force's
    work, to the solver's tolerance. The strain energy is assembled from the problem's
    own form, the force summed from the multipliers: two independent computations.
    """
    from admm_dolfinx.adapt.estimator import relative_energy_error

    scene = lib.flat_punch_graded(MPI.COMM_WORLD, level=0, depth=depth)
    problem = scene.problem()
    with ad.ADMMSolver(problem) as solver:
        result = solver.solve()
    assert result.converged
    force = float(np.linalg.norm(result.contact_force))
    eta2 = 1e-3 * force * depth  # an error of 0.1 % of the energy, relative
    estimate = relative_energy_error(problem, result, eta2)
    energy = eta2 / estimate + eta2  # a(u_h, u_h), as the estimate's denominator has it
    problem.destroy()
    assert energy == pytest.approx(force * depth, rel=1e-5)  # the solve's tolerance: 1e-7
