"""Bad input gets an error that names the problem and the fix, on every rank.

Each case once gave a misleading message (blamed on a rigid motion, on the Dirichlet
conditions, "use penalty='auto'" while it was set), a bare SystemError from SLEPc, a
raw "error code 92", or was silently ignored.
"""

from __future__ import annotations

import gc
import warnings

import numpy as np
import pytest
import ufl
from dolfinx import fem
from mpi4py import MPI
from petsc4py import PETSc

from admm_dolfinx import ADMMConvergenceError, ADMMSolver, Plane
from admm_dolfinx.problem.material import LinearElastic
from admm_dolfinx.scenes.library import example1, example3

from conftest import problem_from

pytestmark = pytest.mark.timeout(120)
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
        penalty_tol=np.float32(0.01),
        rtol=np.float64(1e-6),
        alpha=np.float32(1.5),
        max_iter=np.int64(200),
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
