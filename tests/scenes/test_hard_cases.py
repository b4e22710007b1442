"""Numerical stability on hard cases: each converges with small KKT residuals and no
NaN, or fails with a clear error. Independent answers where one exists.

The iteration counts of these cases are tabulated in the README by
``benchmarks/hard_cases.py``, which runs the same scenes.
"""

import numpy as np
import pytest
from dolfinx import fem
from dolfinx.fem import petsc as fem_petsc
from mpi4py import MPI

from admm_dolfinx import ADMMSolver, Ball, estimate_penalty
from admm_dolfinx.scenes.hard_cases import CASES, build_case
from admm_dolfinx.scenes.library import example1
from admm_dolfinx.studies.baselines import solve_snes_vi

from conftest import rel_diff


def _check_sane(result, problem, tol=1e-5):
    assert result.converged
    assert np.all(np.isfinite(result.u.x.array)) and np.all(np.isfinite(result.multiplier))
    assert result.kkt.max() <= tol, result.kkt
    assert np.all(result.multiplier >= 0.0)


@pytest.mark.parametrize("name", sorted(CASES))
def test_hard_case_converges_with_small_kkt(name):
    scene = build_case(name, MPI.COMM_WORLD, small=True)
    problem = scene.problem()
    with ADMMSolver(problem, max_iter=3000) as solver:
        result = solver.solve()
    _check_sane(result, problem)


@pytest.mark.parametrize(
    "name",
    [
        "nu=0.49",
        "nu=0.499",
        "gap 0",
        "negative gap",
        "graded mesh",
        "distorted mesh",
        "3D nu=0.499",
        "3D all of Γ_C active",
        "3D negative gap",
    ],
)
def test_hard_case_matches_snes_vi(name):
    scene = build_case(name, MPI.COMM_WORLD, small=True)
    # SNES VI takes bounds: on the ball, along the body's (axis-aligned) normals
    problem = scene.problem(
        contact_normal="body" if isinstance(scene.obstacle, Ball) else "obstacle"
    )
    ref = solve_snes_vi(problem)
    with ADMMSolver(problem, rtol=1e-10, max_iter=3000) as solver:
        result = solver.solve()
    assert rel_diff(result.u.x.array, ref.u.x.array) <= 1e-6


def test_scale_invariance_E_1_to_1e9():
    """E from 1 to 1e9 (load scaled alike): r* scales with E, iterations do not change."""
    its, radii = [], []
    for E in (1.0, 1e3, 1e6, 1e9):
        problem = example1(h=1 / 16, E=E, traction=10.0 * E / 2000.0).problem()
        with ADMMSolver(problem) as solver:
            result = solver.solve()
        its.append(result.iterations)
        radii.append(result.penalty / E)
        _check_sane(result, problem)
    assert len(set(its)) == 1, its
    # λ_max by LOBPCG + multigrid at the default tolerance: invariant up to its error
    np.testing.assert_allclose(radii, radii[0], rtol=1e-6)


def test_nothing_touches_gives_the_elastic_solution():
    scene = example1(h=1 / 16, gap=10.0)
    problem = scene.problem()
    with ADMMSolver(problem) as solver:
        result = solver.solve()
    assert result.num_active == 0 and np.all(result.multiplier == 0.0)
    elastic = fem_petsc.LinearProblem(
        scene.a,
        scene.L,
        bcs=scene.bcs,
        petsc_options_prefix="elastic_nothing_",
        petsc_options={"ksp_type": "preonly", "pc_type": "lu"},
    )
    u_el = elastic.solve()
    assert rel_diff(result.u.x.array, u_el.x.array) <= 1e-6


def test_whole_contact_zone_active_matches_bonded_solution():
    """A huge load presses all of Γ_C onto the foundation: the answer is the linear
    solution with u_y = −g prescribed on Γ_C (an independent linear solve)."""
    scene = example1(h=1 / 16, traction=1e4)
    problem = scene.problem()
    with ADMMSolver(problem, rtol=1e-10) as solver:
        result = solver.solve()
    assert result.num_active == problem.num_contact_nodes
    V = scene.V
    # u_y = −g on Γ_C except at the clamped corner, which is not a contact node
    bottom = fem.locate_dofs_geometrical(
        (V.sub(1), V.sub(1).collapse()[0]),
        lambda x: np.isclose(x[1], 0.0) & (x[0] > 1e-12),
    )
    g = fem.Function(V.sub(1).collapse()[0])
    g.x.array[:] = -0.01
    bonded_bcs = [*scene.bcs, fem.dirichletbc(g, bottom, V.sub(1))]
    bonded = fem_petsc.LinearProblem(
        scene.a,
        scene.L,
        bcs=bonded_bcs,
        petsc_options_prefix="bonded_",
        petsc_options={"ksp_type": "preonly", "pc_type": "lu"},
    )
    assert rel_diff(result.u.x.array, bonded.solve().x.array) <= 1e-7


@pytest.mark.parametrize("factor", [1e-2, 1e2])
def test_extreme_penalty_converges_slowly_and_says_so(factor):
    problem = example1(h=1 / 8, mesher="builtin").problem()
    r_star = estimate_penalty(problem).r
    with ADMMSolver(
        problem, penalty=factor * r_star, max_iter=20000, expert={"anderson": 0, "alpha": 1.0}
    ) as solver:
        result = solver.solve()
    with ADMMSolver(problem, penalty=r_star, expert={"anderson": 0, "alpha": 1.0}) as solver:
        at_r_star = solver.solve()
    _check_sane(result, problem)
    assert result.iterations > 5 * at_r_star.iterations
    assert "slow" in result.warning and "penalty='auto'" in result.warning
    assert "WARNING" in result.summary()
    assert not at_r_star.warning


def test_zero_load_gives_zero_solution():
    scene = example1(h=1 / 8, mesher="builtin", traction=0.0)
    problem = scene.problem()
    with ADMMSolver(problem) as solver:
        result = solver.solve()
    assert np.all(result.u.x.array == 0.0) and result.num_active == 0
