"""The condensed factorisation: A factorised once with its Schur complement onto Γ_C.

Its solves with A + rK are compared with an ordinary factorisation of A + rK, its
Schur complement with the inverse of a block of A⁻¹ (computed with plain solves), and
the r sweeps and ADMM solves that use it with those that do not.
"""

import numpy as np
import pytest
from mpi4py import MPI
from petsc4py import PETSc

from admm_dolfinx import ADMMSolver
from admm_dolfinx.operators.condensed import CondensedOperator
from admm_dolfinx.operators.penalised import PenalisedOperator
from admm_dolfinx.scenes.library import example1, example2, example3
from admm_dolfinx.studies.sweep import sample_penalty

serial_only = pytest.mark.skipif(
    MPI.COMM_WORLD.size > 1, reason="PETSc solves with a Schur complement serially only"
)

SCENES = {
    "example1": lambda: example1(h=1 / 16),
    "hertz (curved, floating)": lambda: example2(level=0),
    "example3 (3D)": lambda: example3(level=0),
}


def _rel(x: PETSc.Vec, y: PETSc.Vec) -> float:
    d = x.copy()
    d.axpy(-1.0, y)
    value = d.norm() / y.norm()
    d.destroy()
    return value


@serial_only
@pytest.mark.parametrize("name", list(SCENES))
def test_solves_match_a_factorisation_of_the_penalised_matrix(name):
    """For several r in turn (one sparse factorisation): the same x as A + rK factorised."""
    problem = SCENES[name]().problem()
    condensed = CondensedOperator(problem, "test_condensed_")
    plain = PenalisedOperator(problem, "test_plain_")
    b = problem.create_vector()
    b.setRandom()
    x, y = b.duplicate(), b.duplicate()
    try:
        for r in (1e2, 3e3, 1e6):
            condensed.set_penalty(r)
            plain.set_penalty(r)
            condensed.solve(b, x)
            plain.solve(b, y)
            assert _rel(x, y) <= 1e-10
    finally:
        for obj in (condensed, plain, b, x, y):
            obj.destroy()


@pytest.mark.parametrize("name", ["example1", "hertz (curved, floating)"])
def test_schur_complement_is_the_inverse_of_a_block_of_the_inverse(name):
    """S_C = ((A + rK)⁻¹)_CC⁻¹ − r K_CC, with (A + rK)⁻¹ from ordinary solves; any ranks."""
    problem = SCENES[name]().problem()
    condensed = CondensedOperator(problem, "test_schur_")
    plain = PenalisedOperator(problem, "test_block_")
    r = 1e3
    plain.set_penalty(r)
    comm = problem.comm
    dofs = comm.bcast(condensed.support.dofs if comm.rank == 0 else None, root=0)
    b, x = problem.create_vector(), problem.create_vector()
    scatter, x0 = PETSc.Scatter.toZero(x)
    block = np.zeros((dofs.size, dofs.size))
    try:
        for j, dof in enumerate(dofs):
            b.set(0.0)
            b.setValue(dof, 1.0)
            b.assemble()
            plain.solve(b, x)
            scatter.scatter(x, x0, addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
            if comm.rank == 0:
                block[:, j] = x0.array[dofs]
        if comm.rank == 0:
            expected = np.linalg.inv(block) - r * condensed.k_cc
            scale = np.abs(expected).max()
            assert np.abs(condensed.schur - expected).max() <= 1e-8 * scale
            assert np.array_equal(condensed.schur, condensed.schur.T)
    finally:
        for obj in (condensed, plain, b, x, scatter, x0):
            obj.destroy()


@serial_only
def test_sweep_factorises_once_and_counts_like_ordinary_factorisations():
    """sample_penalty in 2D: one sparse factorisation for all r, the same counts."""
    problem = example1(h=1 / 16).problem()
    r_values = [500.0, 2000.0, 8000.0]
    num = PETSc.Log.Event("MatCholFctrNum")
    before = num.getPerfInfo()["count"]
    sweep = sample_penalty(problem, r_values)
    assert num.getPerfInfo()["count"] - before == 1
    expected = []
    for r in r_values:
        with ADMMSolver(problem, penalty=r, mode="paper", expert={"condensed": False}) as solver:
            expected.append(solver.solve().iterations)
    np.testing.assert_array_equal(sweep.iterations, expected)


@serial_only
def test_condensed_admm_matches_ordinary():
    problem = example2(level=0).problem()
    with ADMMSolver(problem, penalty=2500.0, polish=False, expert={"condensed": True}) as solver:
        first = solver.solve()
    with ADMMSolver(problem, penalty=2500.0, expert={"condensed": False}) as solver:
        second = solver.solve()
    assert first.iterations == second.iterations
    assert _rel(first.u.x.petsc_vec, second.u.x.petsc_vec) <= 1e-10


def test_condensed_needs_mumps_and_one_process():
    problem = example1(h=1 / 8, mesher="builtin").problem()
    with pytest.raises(ValueError, match="MUMPS factorisation"):
        CondensedOperator(problem, "test_bad_", {"ksp_type": "cg", "pc_type": "gamg"})
    with pytest.raises(ValueError, match="condensed=True needs one process and a MUMPS"):
        ADMMSolver(
            problem,
            penalty=100.0,
            petsc_options={"pc_type": "lu", "pc_factor_mat_solver_type": "petsc"},
            expert={"condensed": True},
        )
    if problem.comm.size > 1:
        with pytest.raises(ValueError, match="condensed=True needs one process"):
            ADMMSolver(problem, penalty=100.0, expert={"condensed": True})
        condensed = CondensedOperator(problem, "test_mpi_")  # r* only
        with pytest.raises(RuntimeError, match="needs one process"):
            condensed.set_penalty(100.0)
        condensed.destroy()


def test_large_contact_sets_fall_back_to_the_iterative_method(monkeypatch):
    """Above MAX_CONDENSED_CONTACT_NODES the automatic choices avoid the dense S_C."""
    import admm_dolfinx.operators.condensed as condensed

    problem = example1(h=1 / 16).problem()  # m = 32
    monkeypatch.setattr(condensed, "MAX_CONDENSED_CONTACT_NODES", 31)
    with ADMMSolver(problem) as solver:
        assert solver.penalty_estimate.details["method"] in ("local", "factorised")
        assert type(solver.operator).__name__ == "PenalisedOperator"
    monkeypatch.setattr(condensed, "MAX_CONDENSED_CONTACT_NODES", 32)
    with ADMMSolver(problem) as solver:
        assert solver.penalty_estimate.details["method"] == "dense"


@serial_only
@pytest.mark.parametrize(
    ("threshold", "given", "expected"), [(None, None, 0), (1, None, 5), (1, 0, 0)]
)
def test_the_ordering_is_metis_on_large_meshes_unless_given(
    monkeypatch, threshold, given, expected
):
    """MUMPS runs the ordering asked for (INFOG(7)), and the solves stay exact under it."""
    import admm_dolfinx.operators.condensed as condensed

    if threshold is not None:
        monkeypatch.setattr(condensed, "CONDENSED_METIS_DOFS", threshold)
    problem = example1(h=1 / 16).problem()
    options = None if given is None else {"mat_mumps_icntl_7": given}
    operator = CondensedOperator(problem, "test_ordering_", options)
    reference = PenalisedOperator(problem, "test_ordering_ref_")
    b, x, y = problem.create_vector(), problem.create_vector(), problem.create_vector()
    try:
        operator.set_penalty(10.0)
        reference.set_penalty(10.0)
        factor = operator.ksp.getPC().getFactorMatrix()
        assert factor.getMumpsInfog(7) == expected
        b.setRandom()
        operator.solve(b, x)
        reference.solve(b, y)
        assert _rel(x, y) <= 1e-10
    finally:
        for obj in (operator, reference, b, x, y):
            obj.destroy()
