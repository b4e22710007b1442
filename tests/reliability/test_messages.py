"""Bad input gets an error that names the problem and the fix, on every rank.

Each case once gave a misleading message (blamed on a rigid motion, on the Dirichlet
conditions, "use penalty='auto'" while it was set), a bare SystemError from SLEPc, a
raw "error code 92", or was silently ignored.
"""

from __future__ import annotations

import dataclasses
import gc
import warnings

import numpy as np
import pytest
import ufl
from dolfinx import fem
from mpi4py import MPI
from petsc4py import PETSc

from admm_dolfinx import ADMMConvergenceError, ADMMSolver, Plane
from admm_dolfinx.admm.messages import slow_convergence_warning
from admm_dolfinx.scenes.library import example1, example3
from admm_dolfinx.scenes.material import LinearElastic

from conftest import problem_from

pytestmark = [pytest.mark.timeout(120), pytest.mark.mpi3]
COMM = MPI.COMM_WORLD


@pytest.fixture(scope="module")
def scene():
    return example1(COMM, h=1 / 8, mesher="builtin")


def _elastic_form(scene, E):
    u, v = ufl.TrialFunction(scene.V), ufl.TestFunction(scene.V)
    E = fem.Constant(scene.mesh, float(E))
    mu, lmbda = E / 2.6, E * 0.3 / (1.3 * 0.4)
    eps = LinearElastic.strain
    return ufl.inner(2 * mu * eps(u) + lmbda * ufl.tr(eps(u)) * ufl.Identity(2), eps(v)) * ufl.dx


def test_negative_modulus_names_the_material(scene):
    with pytest.raises(ValueError, match=r"non-positive diagonal.*E > 0"):
        problem_from(scene, a=_elastic_form(scene, -2000.0))


def test_nan_modulus_names_the_stiffness(scene):
    with pytest.raises(ValueError, match="stiffness A assembled from `a` holds NaN"):
        problem_from(scene, a=_elastic_form(scene, np.nan))


def test_non_symmetric_form_is_refused(scene):
    u, v = ufl.TrialFunction(scene.V), ufl.TestFunction(scene.V)
    skew = scene.a + 100.0 * u[0].dx(1) * v[1] * ufl.dx
    with pytest.raises(ValueError, match="not symmetric"):
        problem_from(scene, a=skew)


def test_missing_load_advice_works(scene):
    with pytest.raises(TypeError, match=r"fem.Constant\(mesh, np.zeros\(gdim\)\)"):
        problem_from(scene, L=None)
    # the advice itself is a valid zero load
    v = ufl.TestFunction(scene.V)
    zero = ufl.dot(fem.Constant(scene.mesh, np.zeros(2)), v) * ufl.dx
    problem = problem_from(scene, L=zero)
    assert problem.load_norm == 0.0


def test_numpy_scalars_are_accepted(scene):
    solver = ADMMSolver(
        problem_from(scene),
        rtol=np.float64(1e-6),
        max_iter=np.int64(200),
        expert={"penalty_tol": np.float32(0.01), "alpha": np.float32(1.5)},
    )
    assert solver.solve().converged


def test_misspelt_option_is_named(scene):
    with pytest.raises(ValueError, match=r"did not use the option\(s\) \['ksp_rtoll'\]"):
        ADMMSolver(problem_from(scene), penalty=3000.0, petsc_options={"ksp_rtoll": 1e-8})


def test_incompatible_preconditioner_is_explained(scene):
    """GMRES + ILU: serially an inexact step 1 (named), in parallel no ILU (explained)."""
    options = {"ksp_type": "gmres", "pc_type": "ilu"}
    try:
        ADMMSolver(problem_from(scene), petsc_options=options).solve()
    except ADMMConvergenceError as error:
        assert error.result.status == "inexact_step1"
    except RuntimeError as error:
        assert "error 92" in str(error) and "bjacobi" in str(error)
    else:  # pragma: no cover - the solve converged with verified residuals
        pass


@pytest.mark.parametrize("option", [{"mat_mumps_icntl_23": 1}, {"mat_mumps_icntl_14": -90}])
def test_mumps_memory_failure_is_named(option):
    """Too little workspace (a 1 MB cap, or 90 % less than estimated): named as such,
    not blamed on the Dirichlet conditions or a rigid motion."""
    problem = example1(COMM, h=1 / 32, mesher="builtin").problem()
    with pytest.raises(RuntimeError, match=r"MUMPS ran out of memory.*mat_mumps_icntl_14"):
        ADMMSolver(problem, penalty=3000.0, petsc_options=option)


def test_max_iter_advice_depends_on_the_penalty(scene):
    problem = problem_from(scene)
    with pytest.raises(ADMMConvergenceError) as given:
        ADMMSolver(problem, penalty=3000.0, max_iter=3, polish=False).solve()
    assert "penalty='auto'" in str(given.value)
    with pytest.raises(ADMMConvergenceError) as auto:
        ADMMSolver(problem, max_iter=3, polish=False).solve()
    assert "penalty='auto'" not in str(auto.value) and "max_iter" in str(auto.value)


def test_wrong_way_plane_warns(scene):
    flipped = Plane((0.0, -0.01), (0.0, -1.0))  # points into the body's side
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        problem_from(scene, obstacle=flipped)
    if COMM.rank == 0:  # warnings are issued on rank 0 only
        texts = [str(w.message) for w in caught]
        assert any("normal points from the obstacle towards the body" in t for t in texts)


def _live_petsc() -> set[int]:
    gc.collect()
    return {id(o) for o in gc.get_objects() if isinstance(o, PETSc.Object) and o.handle}


@pytest.mark.parametrize("dim", [2, 3])
def test_failed_construction_frees_what_it_built(scene, dim):
    """A construction that fails late (a misspelt step-1 option, found when r* and, in
    3D, the surface metric are built) destroys every PETSc object it created."""
    problem = problem_from(scene) if dim == 2 else example3(COMM, level=0).problem()
    before = _live_petsc()
    try:
        ADMMSolver(problem, petsc_options={"mat_mumps_icntl_99999": 1})
    except ValueError as error:
        kept = error  # the traceback keeps the constructor's locals alive
    else:  # pragma: no cover
        raise AssertionError("the misspelt option was not reported")
    alive = [
        o
        for o in gc.get_objects()
        if isinstance(o, PETSc.Object) and o.handle and id(o) not in before
    ]
    del kept
    assert alive == [], [type(o).__name__ for o in alive]


@pytest.mark.parametrize("pc", ["none", "jacobi"])
def test_a_preconditioner_alone_is_no_step1_solver(scene, pc):
    """preonly + pc none gave PETSc's raw "error code 83" at the first solve."""
    with pytest.raises(ValueError, match=rf"pc_type='{pc}' once.*solves nothing.*cholesky"):
        options = {"ksp_type": "preonly", "pc_type": pc}
        ADMMSolver(problem_from(scene), penalty=3000.0, petsc_options=options)


def test_a_destroyed_problem_is_named(scene):
    problem = problem_from(scene)
    problem.destroy()
    with pytest.raises(RuntimeError, match=r"ContactProblem has been destroyed.*new"):
        ADMMSolver(problem)


def test_gap_at_a_node_fixed_by_a_dirichlet_condition_is_its_true_gap(scene):
    """The clamped corner (0, 0) of Γ_C is not a contact node; its gap to the floor is
    0.01 (it was reported as 0.0, "in contact")."""
    problem = problem_from(scene)
    assert COMM.allreduce(problem.contact.excluded.dofs.size, op=MPI.SUM) == 1
    with ADMMSolver(problem) as solver:
        result = solver.solve()
    gap = result.gap()
    Q = gap.function_space
    x = Q.tabulate_dof_coordinates()[: Q.dofmap.index_map.size_local]
    corner = np.flatnonzero(np.linalg.norm(x[:, :2], axis=1) < 1e-12)
    values = np.concatenate(COMM.allgather(gap.x.array[corner]))
    assert values.tolist() == pytest.approx([0.01], abs=1e-14)
    # and at the contact nodes the gap stays g − N u ≥ −tolerance, 0 in contact
    lam = result.multiplier
    assert np.all(np.abs(gap.x.array[problem.contact.dofs][lam > 0]) <= 1e-8)


def test_slow_solve_advice_fits_the_settings(scene):
    """The slow-solve warning advised "try anderson > 0" with Anderson on."""
    history = {"fpr": list(np.geomspace(1.0, 1e-3, 400))}

    def slow(**settings) -> str:
        """The warning of this scene's solve with ``settings``, had it taken 400 iterations."""
        with ADMMSolver(problem_from(scene), **settings) as solver:
            try:
                result = solver.solve()
            except ADMMConvergenceError as error:  # a slow r by hand may stop short
                result = error.result
        return slow_convergence_warning(dataclasses.replace(result, history=history))

    text = slow(polish=False)
    assert "400 iterations" in text and "anderson" not in text.lower()
    assert "polish=True" in text
    assert "Anderson acceleration (expert={'anderson': 5}" in slow(expert={"anderson": 0})
    assert "penalty='auto'" in slow(penalty=3000.0)


def test_a_problem_on_comm_self_logs_on_every_rank(caplog):
    """A problem of one rank of a parallel run logs there: its rank 0 is that rank."""
    problem = example1(MPI.COMM_SELF, h=1 / 8, mesher="builtin").problem()
    with caplog.at_level("INFO", logger="admm_dolfinx"):
        with ADMMSolver(problem) as solver:
            solver.solve()
    texts = [record.getMessage() for record in caplog.records]
    assert any(text.startswith("ADMM:") for text in texts), texts
    assert any(text.startswith("r* = ") for text in texts), texts
    # a problem on every rank still logs once, on rank 0
    caplog.clear()
    with caplog.at_level("INFO", logger="admm_dolfinx"):
        with ADMMSolver(example1(COMM, h=1 / 8, mesher="builtin").problem()) as solver:
            solver.solve()
    assert bool(caplog.records) == (COMM.rank == 0)


@pytest.mark.parametrize("h", [1e-9, 0.0, 2.0])
def test_example1_refuses_an_absurd_mesh_size(h):
    with pytest.raises(ValueError, match=r"h must (lie in \[1/2048, 1\]|be a positive)"):
        example1(COMM, h=h, mesher="builtin")


def test_a_refused_answer_names_the_force_balance_that_refused_it():
    """The paper's test stopping where only the force balance is off says so."""
    problem = example3(MPI.COMM_WORLD, level=1).problem(contact_normal="body")
    with ADMMSolver(problem, mode="paper", penalty=7e6, rtol=1e-3) as solver:
        with pytest.raises(ADMMConvergenceError) as err:
            solver.solve()
    kkt = err.value.result.kkt
    assert kkt.force_balance > solver.settings.kkt_tol  # the only residual above it
    assert max(kkt.primal_feasibility, kkt.complementarity, kkt.equilibrium) < 0.01
    assert f"force balance {kkt.force_balance:.2e}" in str(err.value)
