"""The multigrid step 1: CG + GAMG with the rigid-body near null space, warm-started, to
inner tolerances tied to the outer residual (the inexact ADMM), and the plan that
chooses it from the mesh's bracket of a factorisation's cost or MUMPS's own analysis."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from petsc4py import PETSc

import admm_dolfinx.admm.plan as plan_module
from admm_dolfinx import ADMMConvergenceError, ADMMSolver
from admm_dolfinx.admm.inexact import SIGMA_FLOATING, SIGMA_HELD, TAU_FLOOR, InexactRule
from admm_dolfinx.linalg.factor_estimate import mumps_estimate
from admm_dolfinx.linalg.factor_prediction import mesh_volume, predict_factorisation
from admm_dolfinx.penalty.estimate import estimate_penalty
from admm_dolfinx.scenes import example1, example3, hertz_sphere

pytestmark = pytest.mark.timeout(600)


def _rel(a, b) -> float:
    return (a - b).norm() / b.norm()


@pytest.mark.parametrize("scene", [lambda: example1(h=1 / 16), lambda: example3(level=1)])
def test_iterative_step1_gives_the_factorised_answer(scene):
    """The same discrete solution as the factorised step 1 (both to rtol 1e-10), with
    converged=True meaning the recomputed KKT residuals meet the tolerance."""
    problem = scene().problem()
    with ADMMSolver(problem, step1="factorised", rtol=1e-10) as direct:
        exact = direct.solve()
    with ADMMSolver(problem, step1="iterative", rtol=1e-10) as iterative:
        assert iterative.plan.step1 == "iterative" and iterative.plan.ksp_rtol == "auto"
        result = iterative.solve()
    assert result.converged and result.kkt.max() <= 1e-10
    assert _rel(result.u.x.petsc_vec, exact.u.x.petsc_vec) <= 1e-8
    assert result.step1.krylov_iterations >= result.step1.solves == result.iterations
    assert result.step1.unconverged == 0
    assert "step 1 (iterative)" in result.summary()


def test_each_step1_solve_meets_its_tolerance_on_the_true_residual():
    """CG stops on the unpreconditioned residual (CG_RESIDUAL_NORM): after every step-1
    solve the residual recomputed from the matrix, ‖b − (A + rK)x‖, is at most the
    tolerance the inexact rule set times ‖b‖ (up to the drift between CG's updated
    residual and the recomputed one); and the test costs no multigrid cycle beyond
    CG's own (one per iteration), where PETSc's default test on the preconditioned
    residual spends two more per warm-started solve (‖Bb‖, and the last residual)."""
    problem = example3(level=1).problem()
    with ADMMSolver(problem, step1="iterative") as solver:
        operator = solver.operator
        assert solver.ksp.getNormType() == PETSc.KSP.NormType.UNPRECONDITIONED
        checked = []
        solve = operator.solve
        PETSc.Log.begin()
        stage = PETSc.Log.Stage("test_step1_solves")

        def checking_solve(b, x):
            stage.push()
            try:
                solve(b, x)
            finally:
                stage.pop()
            residual = b.duplicate()
            operator.matrix.mult(x, residual)
            residual.aypx(-1.0, b)
            checked.append(residual.norm() / b.norm() / operator.rtol)
            residual.destroy()

        operator.solve = checking_solve
        result = solver.solve()
        cycles = PETSc.Log.Event("PCApply").getPerfInfo(stage)["count"]
    assert result.converged and len(checked) == result.iterations >= 2
    assert result.step1.unconverged == 0
    assert max(checked) <= 1.0 + 1e-3
    its = result.step1.krylov_iterations
    assert its <= cycles <= its + result.step1.solves


def test_the_multigrid_sees_the_rigid_body_modes_and_is_set_up_once_per_r():
    """The step-1 matrix carries the near null space (a duplicate() of A would drop it);
    a second solve at the same r (a load step) sets up no new multigrid."""
    problem = example3(level=1).problem()
    with ADMMSolver(problem, step1="iterative") as solver:
        operators = solver.ksp.getPC().getOperators()[1]
        space = operators.getNearNullSpace()
        assert space is not None and len(space.getVecs()) == 6
        assert solver.ksp.getPC().getType() == "gamg"
        PETSc.Log.begin()
        event = PETSc.Log.Event("PCSetUp_GAMG+")  # a multigrid hierarchy built
        solver.solve()
        before = event.getPerfInfo()["count"]
        first = solver.solve()
        assert event.getPerfInfo()["count"] == before  # nothing rebuilt
        warm = solver.solve(warm_start=first)
        assert warm.step1.krylov_iterations < first.step1.krylov_iterations
        # the first inner tolerance follows the warm state's residual: a loose one
        # would throw the warm start away (it cost the whole iteration count again)
        assert warm.converged and warm.iterations <= 2


def test_one_multigrid_hierarchy_serves_r_star_and_step_1():
    """r*'s λ_max preconditions with step 1's multigrid, built on A once: no hierarchy of
    its own, and a new r moves only the coarse operators (no new aggregates, no new
    Galerkin product of A), at the Krylov iteration counts of a hierarchy built afresh on A + rK."""
    problem = example3(level=1).problem()
    PETSc.Log.begin()
    aggregation = PETSc.Log.Event("MatCreateGraph")  # aggregates: a hierarchy built
    galerkin = PETSc.Log.Event("PCGAMG Gal l00")  # the fine Galerkin product
    aggregated, products = aggregation.getPerfInfo()["count"], galerkin.getPerfInfo()["count"]
    with ADMMSolver(problem, step1="iterative") as solver:
        assert solver.penalty_estimate.details["lambda_max_method"] == "multigrid"
        levels = aggregation.getPerfInfo()["count"] - aggregated
        # one hierarchy in all: one graph per coarsening of step 1's multigrid
        assert levels == solver.ksp.getPC().getMGLevels() - 1 >= 1
        # built on A: one Galerkin product of A; the coarse operators of A + rK are
        # then A_l + r K_l (linalg/galerkin.py), with no second product of A
        assert galerkin.getPerfInfo()["count"] - products == 1
        shared = solver.solve()
        solver.set_penalty(2.0 * solver.penalty)
        assert aggregation.getPerfInfo()["count"] - aggregated == levels  # none rebuilt
        fresh_operator = solver.operator.matrix
        b = problem.create_vector()
        problem.assemble_rhs(0.0, b)
        counts = []
        for reuse in (True, False):
            ksp = PETSc.KSP().create(problem.comm)
            ksp.setOperators(fresh_operator)
            if reuse:
                ksp.setPC(solver.ksp.getPC())
            else:
                ksp.getPC().setType("gamg")
            ksp.setType("cg")
            ksp.setTolerances(rtol=1e-8)
            x = b.duplicate()
            x.set(0.0)
            ksp.solve(b, x)
            counts.append(ksp.getIterationNumber())
            ksp.destroy()
            x.destroy()
        b.destroy()
        assert counts[0] <= counts[1] + 2  # the kept hierarchy is as good as a new one
    with ADMMSolver(problem, step1="factorised", rtol=1e-10) as direct:
        exact = direct.solve()
    assert shared.converged
    assert _rel(shared.u.x.petsc_vec, exact.u.x.petsc_vec) <= 1e-5


def test_a_fixed_inner_tolerance_stalls_and_says_so():
    """The reason for the rule: at a fixed ksp_rtol 1e-6 the outer residual stalls at
    the inner error; the error names the fix."""
    problem = example3(level=1).problem()
    options = {"ksp_rtol": 1e-4}
    with ADMMSolver(problem, step1="iterative", petsc_options=options, max_iter=150) as solver:
        with pytest.raises(ADMMConvergenceError, match="drop ksp_rtol from petsc_options"):
            solver.solve()
    with ADMMSolver(problem, step1="iterative", max_iter=150) as solver:
        assert solver.solve().converged


def test_step1_solves_at_their_iteration_limit_are_named_in_the_error():
    """A solve that fails because step 1's Krylov solves stop at their iteration limit
    says so, not "increase max_iter": more outer iterations do not mend the inner
    solver. A limit the user set is reached by design: it is no sign of a failed
    multigrid, whose smoothers are then left as they are."""
    problem = example3(level=1).problem()
    options = {"ksp_max_it": 1}  # every warm-started solve stops after one iteration
    with ADMMSolver(problem, step1="iterative", petsc_options=options, max_iter=8) as solver:
        with pytest.raises(ADMMConvergenceError) as info:
            solver.solve()
        assert solver.operator.careful_bounds == 0
    message = str(info.value)
    step1 = info.value.result.step1
    assert step1.unconverged > 0
    assert f"{step1.unconverged} of the {step1.solves} step-1 solves" in message
    assert "Krylov iteration limit" in message and "increase max_iter" not in message


def test_inexact_rule_is_summable_tied_to_the_residual_and_tightens():
    rule = InexactRule(sigma=1e-3)
    taus = [rule.tolerance(k, None) for k in range(1, 2000)]
    assert all(b <= a for a, b in itertools.pairwise(taus))
    assert sum(taus) < 0.05  # τ_0 ζ(1.5) < 0.03: summable
    assert rule.tolerance(5, 1e-4) == pytest.approx(1e-7)  # σ r_{k-1}
    assert rule.tolerance(5, 1e-20) == TAU_FLOOR
    loose = rule.tolerance(3, 1e-3)
    assert rule.tighten() and rule.tolerance(3, 1e-3) == pytest.approx(loose * 1e-2)
    for _ in range(20):  # each solve at the tighter tolerance, then the check again
        if rule.tolerance(3, 1e-3) <= TAU_FLOOR and not rule.tighten():
            break
        rule.tighten()
    else:
        raise AssertionError("the tolerances never reached their floor")
    assert rule.tolerance(3, 1e-3) == TAU_FLOOR and not rule.tighten()
    assert not InexactRule(1e-8).tighten()  # a fixed tolerance stands
    with pytest.raises(ValueError, match="σ must lie in"):
        InexactRule(sigma=1.0)


def test_the_plan_ties_the_inner_tolerance_to_how_the_body_is_held():
    """σ of the inexact rule: the looser SIGMA_HELD where Dirichlet conditions hold the
    body, SIGMA_FLOATING where the contact alone does; the expert value stands; each
    solve meets the KKT tolerance (the rule's contract, whatever σ)."""
    assert SIGMA_FLOATING < SIGMA_HELD
    held = example3(level=1).problem()
    floating = hertz_sphere(level=0).problem()
    assert floating.rigid_motions.floating and not held.rigid_motions.floating
    for problem, sigma in ((held, SIGMA_HELD), (floating, SIGMA_FLOATING)):
        with ADMMSolver(problem, step1="iterative", polish=False) as solver:
            assert solver.plan.inner_sigma == sigma
            assert f"σ = {sigma:g}" in solver.plan.describe()
            result = solver.solve()
            assert result.converged and result.kkt.max() <= solver.settings.kkt_tol
    with ADMMSolver(held, step1="iterative", expert={"inner_sigma": 0.05}) as solver:
        assert solver.plan.inner_sigma == 0.05 and "σ =" not in solver.plan.describe()
    with ADMMSolver(held, step1="iterative", petsc_options={"ksp_rtol": 1e-9}) as solver:
        assert solver.plan.inner_sigma is None  # a fixed tolerance has no rule
    with ADMMSolver(held, step1="factorised") as solver:
        assert solver.plan.inner_sigma is None


@pytest.mark.parametrize(
    "given, message",
    [
        ({"step1": "factorised", "petsc_options": {"ksp_type": "cg"}}, "conflicts"),
        ({"step1": "iterative", "petsc_options": {"ksp_type": "preonly"}}, "conflicts"),
        ({"step1": "factorised", "petsc_options": {"ksp_rtol": 1e-8}}, "solves exactly"),
        ({"petsc_options": {"ksp_rtol": 1e-8}}, "pass step1='iterative'"),
        ({"step1": "iterative", "polish": True}, "Schur complement"),
        ({"step1": "direct"}, "step1 must be one of"),
        ({"step1": "iterative", "petsc_options": {"ksp_rtol": 2.0}}, r"\(0, 1\)"),
        ({"step1": "iterative", "expert": {"inner_sigma": 0.0}}, r"inner_sigma must lie"),
        (
            {
                "step1": "iterative",
                "petsc_options": {"ksp_rtol": 1e-8},
                "expert": {"inner_sigma": 0.01},
            },
            "ksp_rtol fixes",
        ),
        ({"step1": "factorised", "expert": {"inner_sigma": 0.01}}, "may be factorised"),
        ({"expert": {"inner_sigma": 0.01}}, "may be factorised"),  # step1="auto"
    ],
)
def test_step1_settings_conflicts_raise(given, message):
    from admm_dolfinx import ADMMSettings

    with pytest.raises(ValueError, match=message):
        ADMMSettings.create(**given)


@pytest.mark.parametrize("paper", [False, True])
def test_the_step1_rule_is_monotone_in_the_cost(paper):
    """What makes the mesh's bracket enough: a factorisation chosen at some (flops,
    memory) is chosen at every smaller cost, so where both ends of the bracket choose
    alike, any cost inside it (MUMPS's) chooses the same. Checked on a grid that
    crosses every threshold (the flop limit, memory), in every mode."""
    rule = plan_module._StepOneRule(memory=8e9, paper=paper)
    flops = np.geomspace(1e8, 1e15, 29)
    memory = np.geomspace(1e7, 1e11, 17)
    iterative = np.array([[rule.iterative_at(f, m)[0] for m in memory] for f in flops])
    assert np.all(np.diff(iterative.astype(int), axis=0) >= 0)  # more flops: never back
    assert np.all(np.diff(iterative.astype(int), axis=1) >= 0)  # more memory: never back
    assert not iterative[0, 0] and iterative[-1, -1]
    # the flop limit, and only memory in the paper's mode
    limit = plan_module.FACTOR_FLOPS_LIMIT
    assert rule.iterative_at(limit / 2, 1e8)[0] is False
    assert rule.iterative_at(limit * 2, 1e8)[0] == (not paper)


def test_the_plan_asks_mumps_analysis_and_says_why(monkeypatch):
    """3D, step1='auto', no options: the mesh's bracket of a factorisation's cost
    decides where all of it lies on one side of the thresholds, without MUMPS's
    analysis; where it straddles one, the analysis decides. Factorised while the cost
    is small; above the flop limit, or beyond the memory budget, multigrid, with the
    reason given."""
    problem = example3(level=1).problem()
    analyses = []

    def counted(A, **kwargs):
        analyses.append(A.getSize()[0])
        return mumps_estimate(A, **kwargs)

    monkeypatch.setattr(plan_module, "mumps_estimate", counted)
    with ADMMSolver(problem) as solver:
        assert solver.plan.step1 == "factorised" and solver.plan.step1_basis == "mesh"
        assert "analysis not needed" in solver.plan.describe()
    assert not analyses
    # a limit inside the bracket: MUMPS's analysis decides, and its figures are given
    sides = problem.bounds[1] - problem.bounds[0]
    bracket = predict_factorisation(sides, mesh_volume(problem.mesh), problem.A.getSize()[0])
    estimate = mumps_estimate(problem.A)
    for limit, chosen in [
        (estimate.flops * 1.5, "factorised"),
        (estimate.flops / 1.5, "iterative"),
    ]:
        assert bracket.flops[0] < limit < bracket.flops[1]
        monkeypatch.setattr(plan_module, "FACTOR_FLOPS_LIMIT", limit)
        with ADMMSolver(problem) as solver:
            assert solver.plan.step1 == chosen and solver.plan.step1_basis == "analysis"
            assert "GB and" in solver.plan.describe()
    assert len(analyses) == 2
    monkeypatch.setattr(plan_module, "FACTOR_FLOPS_LIMIT", 1.0)
    with ADMMSolver(problem) as solver:
        assert solver.plan.step1 == "iterative" and "flops" in solver.plan.describe()
        assert solver.plan.step1_basis == "mesh"
        assert solver.solve().converged
    # the paper's algorithm factorises wherever it fits, and says so (it switched to
    # multigrid on Table 6's largest mesh)
    paper = example3(level=1).problem(contact_normal="body")
    with ADMMSolver(paper, mode="paper") as solver:
        assert solver.plan.step1 == "factorised"
        assert "as the paper's algorithm" in solver.plan.describe()
    monkeypatch.setattr(plan_module, "FACTOR_FLOPS_LIMIT", 1e30)
    monkeypatch.setattr(plan_module, "available_memory", lambda: 1e3)
    with ADMMSolver(problem) as solver:
        assert solver.plan.step1 == "iterative" and "available" in solver.plan.describe()
    with ADMMSolver(paper, mode="paper") as solver:  # unless it does not fit
        assert solver.plan.step1 == "iterative" and "available" in solver.plan.describe()
    assert len(analyses) == 2
    with ADMMSolver(problem, step1="factorised") as solver:  # the user's choice stands
        assert solver.plan.step1 == "factorised"


def test_a_floating_body_on_the_multigrid_path_factorises_nothing(monkeypatch):
    """r*'s λ_max of a floating body (A alone is singular) on the multigrid path: LOBPCG
    with the free rigid motion deflated, preconditioned by step 1's multigrid of
    A + r_a K (the method says so), never a factorisation of the body that the plan
    found too large for one (nor of a private operator: the guard below). λ_max is the
    exact pencil's (dense, rigid motions deflated) to the eigenvalue tolerance, and the
    solve is exact (polished)."""
    import admm_dolfinx.penalty.estimate as estimate_module

    problem = hertz_sphere(level=1).problem()
    exact = estimate_penalty(problem, method="dense")

    def no_factorisation(*args, **kwargs):
        raise AssertionError("r* factorised the body on the multigrid path")

    monkeypatch.setattr(estimate_module, "PenalisedOperator", no_factorisation)
    with ADMMSolver(problem, step1="iterative") as solver:
        estimate = solver.penalty_estimate
        assert estimate.details["lambda_max_method"] == "multigrid"
        assert estimate.details["rigid_modes"] == 1
        # step 1's multigrid, set up by r* at r_a: r*'s time counts it
        assert not estimate.details["multigrid_shared"]
        assert estimate.details["time_multigrid_setup"] > 0.0
        result = solver.solve()
    assert estimate.lambda_max == pytest.approx(exact.lambda_max, rel=estimate.details["tol"])
    assert result.converged and result.polish.polished_at == 2


def _without_multigrid_lambda_max(monkeypatch):
    """Make r*'s λ_max fall back to Krylov–Schur with step 1's Krylov solves."""
    import admm_dolfinx.penalty.estimate as estimate_module
    from admm_dolfinx.penalty.lambda_max import NeedsFactorisation

    def refuse(*args, **kwargs):
        raise NeedsFactorisation("refused by the test")

    monkeypatch.setattr(estimate_module, "lambda_max_multigrid", refuse)


def test_a_floating_body_falls_back_to_krylov_schur_with_step1_solves(monkeypatch):
    """Where LOBPCG does not apply, a floating body's λ_max is Krylov–Schur on the
    compliance, applied by step 1's own CG + GAMG (still no factorisation): λ_max is
    the factorised Krylov–Schur's to well under the eigenvalue tolerance."""
    import admm_dolfinx.penalty.estimate as estimate_module

    problem = hertz_sphere(level=1).problem()
    with ADMMSolver(problem, step1="factorised", polish=False) as solver:
        reference = solver.penalty_estimate
    assert reference.details["lambda_max_method"] == "factorised"

    def no_factorisation(*args, **kwargs):
        raise AssertionError("r* factorised the body on the multigrid path")

    monkeypatch.setattr(estimate_module, "PenalisedOperator", no_factorisation)
    _without_multigrid_lambda_max(monkeypatch)
    with ADMMSolver(problem, step1="iterative") as solver:
        estimate = solver.penalty_estimate
        assert estimate.details["lambda_max_method"] == "factorised"  # the same Krylov–Schur
        result = solver.solve()
    # its Krylov solves stop at a fraction of the eigenvalue tolerance
    close = 1e-2 * estimate.details["tol"]
    assert estimate.lambda_max == pytest.approx(reference.lambda_max, rel=close)
    assert estimate.r == pytest.approx(reference.r, rel=close)
    assert result.converged and result.polish.polished_at == 2


def test_a_floating_body_whose_lambda_max_solves_stop_at_their_limit_is_refused(monkeypatch):
    """An iteration limit in the step-1 options that stops λ_max's Krylov solves (the
    Krylov–Schur fallback) is named, on every rank, instead of an eigenvalue of
    unconverged solves."""
    _without_multigrid_lambda_max(monkeypatch)
    problem = hertz_sphere(level=1).problem()
    with pytest.raises(RuntimeError, match="iteration limit"):
        ADMMSolver(problem, step1="iterative", petsc_options={"ksp_max_it": 2})


def _no_factorisation(*args, **kwargs):
    raise AssertionError("r* factorised the body on the multigrid path")


def _factorised_reference(problem):
    """r* of the factorised step 1 (Krylov–Schur on the factorised compliance)."""
    with ADMMSolver(problem, step1="factorised", polish=False) as solver:
        reference = solver.penalty_estimate
    assert reference.details["lambda_max_method"] == "factorised"
    return reference


def test_a_floating_body_whose_step1_has_no_multigrid_takes_krylov_schur(monkeypatch):
    """Step-1 options without multigrid (CG + Jacobi): step 1 has no multigrid of
    A + r_a K to precondition LOBPCG, so r*'s λ_max takes the Krylov–Schur route with
    step 1's own Krylov solves (no factorisation), the factorised λ_max to well under
    the eigenvalue tolerance, and the solve that follows meets the KKT tolerance."""
    import admm_dolfinx.penalty.estimate as estimate_module
    import admm_dolfinx.penalty.lambda_max as lambda_max_module

    problem = hertz_sphere(level=1).problem()
    reference = _factorised_reference(problem)
    lobpcg_runs: list[int] = []
    lobpcg = lambda_max_module.largest_generalized_eigenpair

    def spy(*args, **kwargs):
        lobpcg_runs.append(1)
        return lobpcg(*args, **kwargs)

    monkeypatch.setattr(lambda_max_module, "largest_generalized_eigenpair", spy)
    monkeypatch.setattr(estimate_module, "PenalisedOperator", _no_factorisation)
    with ADMMSolver(
        problem, step1="iterative", petsc_options={"ksp_type": "cg", "pc_type": "jacobi"}
    ) as solver:
        assert solver.operator.ksp.getPC().getType() == PETSc.PC.Type.JACOBI
        estimate = solver.penalty_estimate
        assert estimate.details["lambda_max_method"] == "factorised"
        assert not lobpcg_runs  # LOBPCG never ran
        result = solver.solve()
    close = 1e-2 * estimate.details["tol"]
    assert estimate.lambda_max == pytest.approx(reference.lambda_max, rel=close)
    assert result.converged and result.kkt.max() <= 1e-6


def test_a_floating_body_whose_lobpcg_fails_after_moving_step1_falls_back(monkeypatch):
    """LOBPCG failing after it moved step 1's multigrid to its r_a: the Krylov–Schur
    fallback (which sets step 1 to each r_a itself) gives the factorised λ_max, step
    1 is then at the solver's r, and the solve meets the KKT tolerance."""
    import admm_dolfinx.penalty.estimate as estimate_module
    import admm_dolfinx.penalty.lambda_max as lambda_max_module
    from admm_dolfinx.operators.penalised import IterativeOperator

    problem = hertz_sphere(level=1).problem()
    reference = _factorised_reference(problem)
    moved: list[float] = []
    multigrid_at = IterativeOperator.multigrid_at

    def spy(self, r):
        moved.append(r)
        return multigrid_at(self, r)

    def fail(*args, **kwargs):
        raise RuntimeError("LOBPCG did not converge (made to fail by the test)")

    monkeypatch.setattr(IterativeOperator, "multigrid_at", spy)
    monkeypatch.setattr(lambda_max_module, "largest_generalized_eigenpair", fail)
    monkeypatch.setattr(estimate_module, "PenalisedOperator", _no_factorisation)
    with ADMMSolver(problem, step1="iterative") as solver:
        estimate = solver.penalty_estimate
        assert moved, "LOBPCG's route did not set step 1's multigrid up before it failed"
        assert estimate.details["lambda_max_method"] == "factorised"
        result = solver.solve()
        assert solver.operator.penalty == pytest.approx(result.penalty)
    close = 1e-2 * estimate.details["tol"]
    assert estimate.lambda_max == pytest.approx(reference.lambda_max, rel=close)
    assert result.converged and result.kkt.max() <= 1e-6
