"""Active-set polishing against independent answers: SNES VI, tight unpolished ADMM, KKT.

Runs serially and under ``mpiexec -n 2`` (there the polisher reads S_C from a private
condensed factorisation and the ADMM solves with a factorisation of A + r*K).
"""

import functools
import itertools

import numpy as np
import pytest
from mpi4py import MPI

import admm_dolfinx.admm.polish_dense as polish_module
from admm_dolfinx import ADMMSolver
from admm_dolfinx.admm.polish_sparse import SparsePolish
from admm_dolfinx.scenes.library import example1, example2, example3, hertz_sphere
from admm_dolfinx.studies.baselines import solve_snes_vi

from conftest import rel_diff


def _global(problem, local):
    return np.concatenate(problem.comm.allgather(np.asarray(local)))


@pytest.mark.parametrize("h", [1 / 16, 1 / 32])
def test_polished_solution_matches_snes_vi(h):
    problem = example1(h=h).problem()
    with ADMMSolver(problem, polish=False) as solver:
        plain = solver.solve()
    with ADMMSolver(problem) as solver:  # the default polishes in 2D
        assert solver.polish
        result = solver.solve()
    ref = solve_snes_vi(problem)
    info = result.polish
    assert info["polished_at"] == result.iterations  # the polished state met the test
    assert result.polished and not plain.polished
    assert result.history["accelerated"][-1] == 2
    assert result.iterations < plain.iterations
    # exact, not merely within the stopping tolerance (1e-6)
    assert result.kkt.max() <= 1e-10
    assert rel_diff(_global(problem, result.u.x.array), _global(problem, ref.u.x.array)) <= 1e-9
    assert rel_diff(_global(problem, result.multiplier), _global(problem, ref.multiplier)) <= 1e-8


def test_polish_on_a_floating_curved_body():
    """Hertz: curved Γ_C (two dofs per contact node in C), held by contact alone."""
    problem = example2(level=1).problem()
    with ADMMSolver(problem, polish=False, rtol=1e-11, max_iter=3000) as solver:
        tight = solver.solve()
    with ADMMSolver(problem) as solver:
        result = solver.solve()
    assert result.polish.polished_at == result.iterations
    assert result.kkt.max() <= 1e-10
    assert rel_diff(_global(problem, result.u.x.array), _global(problem, tight.u.x.array)) <= 1e-8
    assert rel_diff(_global(problem, result.multiplier), _global(problem, tight.multiplier)) <= 1e-8


def _one_step(solver):
    """(N u, q) of one step-1 solve from p = min(0, g), λ = 0."""
    problem = solver.problem
    r = solver.penalty
    b, x = problem.create_vector(), problem.create_vector()
    problem.assemble_rhs(r, b)
    q = r * np.minimum(0.0, problem.contact.gap)
    problem.add_normal_force(b, q)
    solver.operator.solve(b, x)
    normal_u = problem.apply_normal(x)
    b.destroy()
    x.destroy()
    return normal_u, q


def test_attempt_gives_the_exact_state_from_the_true_active_set(monkeypatch):
    """The walk from a given set (the refinement of the guess on Γ_C off, so that the
    masks below are the guesses themselves)."""
    monkeypatch.setattr(polish_module, "INNER_MAX_ITERATIONS", 0)
    problem = example1(h=1 / 16).problem()
    ref = solve_snes_vi(problem)
    true_active = ref.multiplier > 1e-8 * np.max(_global(problem, ref.multiplier))
    with ADMMSolver(problem) as solver:
        polisher = solver.polisher
        polisher.reset()
        normal_u, q = _one_step(solver)
        exact = polisher.attempt(normal_u, q, true_active)
        assert exact is not None
        p, lam = exact
        p_ref = np.minimum(problem.apply_normal(ref.u.x.petsc_vec), problem.contact.gap)
        assert rel_diff(_global(problem, lam), _global(problem, ref.multiplier)) <= 1e-8
        assert rel_diff(_global(problem, p), _global(problem, p_ref)) <= 1e-8
        # the outcome depends on the guess alone: a guess tried before is not retried
        rounds = polisher.rounds
        assert polisher.attempt(normal_u, q, true_active) is None
        assert polisher.rounds == rounds
        # every node active: λ < 0 where the body lifts off; the corrections drop them
        everything = polisher.attempt(normal_u, q, np.ones_like(true_active))
        if everything is not None:
            assert rel_diff(_global(problem, everything[1]), _global(problem, lam)) <= 1e-10
        # no guess: the corrections start from the unconstrained solution
        empty = polisher.attempt(normal_u, q, np.zeros_like(true_active))
        if empty is not None:
            assert rel_diff(_global(problem, empty[1]), _global(problem, lam)) <= 1e-10
        # out of time: skipped, not tried
        polisher.reset()
        assert polisher.attempt(normal_u, q, true_active, budget=-1.0) is None
        assert (polisher.skipped, polisher.attempts, polisher.rounds) == (1, 0, 0)
        assert polisher.attempt(normal_u, q, true_active) is not None


@pytest.mark.parametrize("kind", ["dense", "sparse"])
def test_a_walk_cut_short_by_its_round_limit_is_resumed(kind, monkeypatch):
    """Attempts that join a walk stopped by its round limit go on where it stopped.

    (The walk alone: the dense polisher's refinement of the guess on Γ_C is off.)

    The corrections depend on the active set alone, so attempts of one round each,
    all from the same guess, reach the solution that one long walk reaches, and
    together compute each correction once (the edge of the contact zone moves by about
    half its error per round: on fine meshes a walk needs more rounds than one attempt
    may take).
    """
    monkeypatch.setattr(polish_module, "INNER_MAX_ITERATIONS", 0)
    problem = example1(h=1 / 32).problem()
    with ADMMSolver(problem) as solver:
        normal_u, q = _one_step(solver)
        polisher = solver.polisher if kind == "dense" else SparsePolish(problem, "test_walk_")
        try:
            empty = np.zeros(problem.contact.gap.size, dtype=bool)
            polisher.reset()
            polisher.max_rounds = 100
            long_walk = polisher.attempt(normal_u, q, empty)
            needed = polisher.rounds
            assert long_walk is not None and needed >= 3
            polisher.reset()
            polisher.max_rounds = 1
            outcomes = [polisher.attempt(normal_u, q, empty) for _ in range(needed)]
            assert all(outcome is None for outcome in outcomes[:-1])
            assert outcomes[-1] is not None
            assert polisher.rounds == needed  # no correction computed twice
            for resumed, whole in zip(outcomes[-1], long_walk, strict=True):
                assert rel_diff(_global(problem, resumed), _global(problem, whole)) <= 1e-10
            # the walk has ended: the same guess gives nothing new, at no cost
            assert polisher.attempt(normal_u, q, empty) is None
            assert polisher.rounds == needed
        finally:
            if kind == "sparse":
                polisher.destroy()


def test_failed_attempts_leave_the_iteration_converging(monkeypatch):
    """One dense solve per guess, no correction (and no refinement of the guess on
    Γ_C): the ADMM carries on until one works."""
    monkeypatch.setattr(polish_module, "INNER_MAX_ITERATIONS", 0)
    problem = example1(h=1 / 32).problem()
    with ADMMSolver(problem) as solver:
        default = solver.solve()
    with ADMMSolver(problem, expert={"polish_rounds": 1}) as solver:
        result = solver.solve()
    assert result.polish.attempts >= 2
    assert result.kkt.max() <= 1e-6
    assert rel_diff(_global(problem, result.u.x.array), _global(problem, default.u.x.array)) <= 1e-6


def test_an_error_in_the_dense_work_switches_polishing_off_on_every_rank(monkeypatch, caplog):
    """The dense work runs on rank 0 alone: an exception there (here planted in the
    compliance, then in an attempt) is a warning and an unpolished solve, on every
    rank alike, never a rank that raises while the others wait."""
    problem = example1(h=1 / 32).problem()
    with ADMMSolver(problem, polish=False) as solver:
        plain = solver.solve()

    def fail(*args, **kwargs):
        raise MemoryError("planted")

    with monkeypatch.context() as patch:
        patch.setattr(polish_module, "compliance_matrix", fail)
        with ADMMSolver(problem) as solver, caplog.at_level("WARNING"):
            result = solver.solve()
    assert not result.polished and result.polish.attempts == 0
    assert result.iterations == plain.iterations  # the plain iteration, untouched
    with monkeypatch.context() as patch:
        patch.setattr(polish_module.ActiveSetPolish, "_solve", fail)
        with ADMMSolver(problem) as solver, caplog.at_level("WARNING"):
            result = solver.solve()
    assert not result.polished and result.polish.attempts > 0
    assert result.converged and result.kkt.max() <= 1e-6
    if problem.comm.rank == 0:
        assert "MemoryError: planted" in caplog.text


def test_polish_options():
    problem = example1(h=1 / 8).problem()
    with ADMMSolver(problem, mode="paper") as solver:
        assert solver.polisher is None
        result = solver.solve()
    assert result.settings.polish is False and result.polish is None
    assert 2 not in result.history["accelerated"]
    with ADMMSolver(problem, penalty=3000.0) as solver:  # no S_C at hand: off by default
        assert solver.polisher is None
    with ADMMSolver(problem, penalty=3000.0, polish=True) as solver:
        assert solver.solve().polish.polished_at is not None
    with pytest.raises(TypeError, match="polish must be None"):
        ADMMSolver(problem, polish="yes")
    with pytest.raises(ValueError, match="polish=True needs the Schur complement"):
        ADMMSolver(problem, polish=True, petsc_options={"ksp_type": "cg", "pc_type": "gamg"})


def test_polish_in_3d_on_request():
    """3D: off by default (S_C of a surface costs more than it saves); on request exact."""
    problem = example3(level=0).problem()
    with ADMMSolver(problem, rtol=1e-11) as solver:
        assert solver.polisher is None
        default = solver.solve()
    with ADMMSolver(problem, polish=True) as solver:
        result = solver.solve()
    assert result.polish.polished_at == result.iterations
    assert result.kkt.max() <= 1e-10
    assert rel_diff(_global(problem, result.u.x.array), _global(problem, default.u.x.array)) <= 1e-9
    assert MPI.COMM_WORLD.allreduce(result.multiplier.size) == problem.num_contact_nodes


def test_a_floating_3d_body_polishes_by_default():
    """3D, held by the contact alone: the default polishes (where S_C is cheap), exactly.

    Unpolished, the ADMM builds the contact zone of a floating body a few nodes per
    iteration (``python benchmarks/polish_3d.py --scene hertz_sphere`` counts both).
    """
    problem = hertz_sphere(level=0).problem()
    assert problem.rigid_motions.floating
    with ADMMSolver(problem, polish=False, rtol=1e-11, max_iter=3000) as solver:
        assert solver.polisher is None and solver.plan.metric == "surface"
        tight = solver.solve()
    with ADMMSolver(problem) as solver:
        assert solver.plan.polish == "dense"
        result = solver.solve()
    assert result.polish.polished_at == result.iterations < tight.iterations
    assert result.kkt.max() <= 1e-10
    assert rel_diff(_global(problem, result.u.x.array), _global(problem, tight.u.x.array)) <= 1e-8
    assert rel_diff(_global(problem, result.multiplier), _global(problem, tight.multiplier)) <= 1e-8


def test_polish_with_prescribed_tangential_displacement_on_a_curved_contact_boundary():
    """u_x = 0.003 prescribed on a curved Γ_C: the fixed part of each normal moves the
    node towards the obstacle by a known amount, which the polished system must carry."""
    import ufl
    from dolfinx import fem, mesh

    from admm_dolfinx import ContactProblem, Plane

    comm = MPI.COMM_WORLD
    msh = mesh.create_rectangle(comm, [[0, 0], [2, 1]], [24, 12])
    x = msh.geometry.x
    x[:, 1] += 0.2 * (x[:, 0] - 1.0) ** 2 * (1.0 - x[:, 1])  # bottom y = 0.2 (x − 1)²
    bottom = mesh.locate_entities_boundary(
        msh, 1, lambda p: np.isclose(p[1], 0.2 * (p[0] - 1.0) ** 2)
    )
    top = mesh.locate_entities_boundary(msh, 1, lambda p: np.isclose(p[1], 1.0))
    facets = np.concatenate([bottom, top])
    values = np.concatenate([np.full(bottom.size, 3), np.full(top.size, 2)]).astype(np.int32)
    order = np.argsort(facets)
    tags = mesh.meshtags(msh, 1, facets[order], values[order])
    V = fem.functionspace(msh, ("Lagrange", 1, (2,)))
    u, v = ufl.TrialFunction(V), ufl.TestFunction(V)
    mu, lmbda = 2000.0 / 2.6, 2000.0 * 0.3 / (1.3 * 0.4)
    eps = ufl.sym(ufl.grad(u))
    a = ufl.inner(2 * mu * eps + lmbda * ufl.tr(eps) * ufl.Identity(2), ufl.sym(ufl.grad(v)))
    ds = ufl.Measure("ds", domain=msh, subdomain_data=tags)
    L = ufl.dot(fem.Constant(msh, (0.0, -20.0)), v) * ds(2)
    V0 = V.sub(0)
    V0c, _ = V0.collapse()
    shift = fem.Function(V0c)
    shift.x.array[:] = 0.003
    bc = fem.dirichletbc(shift, fem.locate_dofs_topological((V0, V0c), 1, bottom), V0)
    problem = ContactProblem(a * ufl.dx, L, [bc], tags, 3, Plane((0.0, -0.002), (0.0, 1.0)))
    with ADMMSolver(problem, polish=False, rtol=1e-11, max_iter=5000) as solver:
        tight = solver.solve()
    with ADMMSolver(problem) as solver:
        result = solver.solve()
    assert result.polished and 0 < result.num_active < problem.num_contact_nodes
    assert result.kkt.max() <= 1e-10
    assert rel_diff(_global(problem, result.u.x.array), _global(problem, tight.u.x.array)) <= 1e-9
    assert rel_diff(_global(problem, result.multiplier), _global(problem, tight.multiplier)) <= 1e-8


def _no_condensed_rule(monkeypatch):
    """Γ_C past the condensed rule, whatever its size: S_C is never computed unasked."""
    import admm_dolfinx.operators.condensed as condensed

    monkeypatch.setattr(condensed, "DENSE_COST_RATIO", 0.0)


def test_a_floating_3d_body_past_the_condensed_rule_polishes_from_the_step1_factors(
    monkeypatch,
):
    """T is read off step 1's factors (inverse entries), exactly, on any partition.

    Compared with the same body polished from S_C and with a tight unpolished solve.
    Under MPI the step-1 factorisation takes a centralised right-hand side (MUMPS
    reads the inverse entries with one).
    """
    problem = hertz_sphere(level=0).problem()
    with ADMMSolver(problem) as solver:
        assert solver.plan.polish == "dense"
        dense = solver.solve()
    with ADMMSolver(problem, polish=False, rtol=1e-11, max_iter=3000) as solver:
        tight = solver.solve()
    _no_condensed_rule(monkeypatch)
    with ADMMSolver(problem) as solver:
        plan = solver.plan
        result = solver.solve()
    u, lam = _global(problem, result.u.x.array), _global(problem, result.multiplier)
    centralised = plan.step1_options.get("mat_mumps_icntl_20") == 0
    assert centralised == (problem.comm.size > 1)
    assert plan.polish == "inverse" and plan.step1 == "factorised" and plan.metric == "mass"
    assert result.polish.kind == "inverse"
    assert result.polish.polished_at == result.iterations < tight.iterations
    assert result.kkt.max() <= 1e-10
    assert rel_diff(u, _global(problem, dense.u.x.array)) <= 1e-9
    assert rel_diff(lam, _global(problem, dense.multiplier)) <= 1e-8
    assert rel_diff(u, _global(problem, tight.u.x.array)) <= 1e-8


def test_a_floating_3d_body_past_the_flop_limit_is_polished_on_the_multigrid_path(
    monkeypatch,
):
    """Past FACTOR_FLOPS_LIMIT a floating body takes multigrid as a held one does, and
    is polished there (its walk solves by multigrid): it no longer keeps a
    factorisation for polishing from its factors."""
    import admm_dolfinx.admm.plan as plan_module

    _no_condensed_rule(monkeypatch)
    held, floating = example3(level=0).problem(), hertz_sphere(level=0).problem()
    with ADMMSolver(floating) as solver:
        assert solver.plan.step1 == "factorised" and solver.plan.polish == "inverse"
    monkeypatch.setattr(plan_module, "FACTOR_FLOPS_LIMIT", 1.0)
    with ADMMSolver(held) as solver:
        assert solver.plan.step1 == "iterative"
    with ADMMSolver(floating) as solver:
        assert solver.plan.step1 == "iterative" and solver.plan.step1_basis == "mesh"
        # the active-set walk solves by multigrid
        assert solver.plan.polish == "sparse" and solver.plan.metric == "surface"
    with ADMMSolver(held) as solver:
        assert solver.plan.polish == "none"  # a held body creeps not: no walk
    with ADMMSolver(floating, polish=False) as solver:
        assert solver.plan.polish == "none"


@pytest.mark.parametrize("level", [1, 2])
def test_a_floating_body_on_the_multigrid_path_is_polished_by_multigrid(level):
    """The active-set walk of the multigrid path: Â solved by CG + GAMG to
    POLISH_RTOL_FACTOR × kkt_tol, the polished state handed to step 1 as its start.

    Two iterations as with the factorised step 1 (unpolished, the same step 1 needs
    well over a hundred), on any partition, and the exact answer: the factorised
    default's (polished from S_C) to well under the KKT tolerance.
    """
    problem = hertz_sphere(level=level).problem()
    with ADMMSolver(problem) as solver:
        exact = solver.solve()
    with ADMMSolver(problem, step1="iterative") as solver:
        assert solver.plan.polish == "sparse"
        assert solver.polisher.iterative
        result = solver.solve()
        walk = solver.polisher.krylov_iterations
    assert result.converged and result.kkt.max() <= solver.settings.kkt_tol / 10
    assert result.polish.kind == "sparse"
    assert result.polish.polished_at == result.iterations == 2
    assert result.polish.krylov_iterations == walk >= result.polish.rounds >= 2
    # the polished state's step-1 solve starts at its solution: a few Krylov steps
    assert result.step1.krylov_iterations <= 10
    u, lam = _global(problem, result.u.x.petsc_vec.array), _global(problem, result.multiplier)
    assert rel_diff(u, _global(problem, exact.u.x.petsc_vec.array)) <= 1e-8
    assert rel_diff(lam, _global(problem, exact.multiplier)) <= 1e-8


def test_the_multigrid_walk_remembers_no_coarse_step(monkeypatch):
    """A step read from a coarse solve is not the set's exact step: the walk forgets it,
    so that a later attempt computes it again instead of following it. With every
    moving round coarse, the steps remembered after the solve are tight ones only."""
    import admm_dolfinx.admm.polish_sparse as sparse_module

    monkeypatch.setattr(sparse_module, "COARSE_MOVES", 0.0)
    problem = hertz_sphere(level=1).problem()
    with ADMMSolver(problem, step1="iterative") as solver:
        polisher = solver.polisher
        solved: list[tuple[np.ndarray, float]] = []
        equality_solution = polisher._equality_solution

        def recording(active, rtol):
            solved.append((active.copy(), rtol))
            return equality_solution(active, rtol)

        monkeypatch.setattr(polisher, "_equality_solution", recording)
        result = solver.solve()
        assert result.converged and result.polish.polished_at == 2
        coarse = {polisher._key(a) for a, rtol in solved if rtol == sparse_module.COARSE_RTOL}
        tight = {polisher._key(a) for a, rtol in solved if rtol == polisher.solve_rtol}
        remembered = set(polisher._walk._next)
        assert coarse - tight  # some sets were stepped from coarsely only
        assert not remembered & (coarse - tight)
        assert remembered  # the tight steps (the answer's) are kept


def _record_rounds(monkeypatch, problem, polisher) -> list[tuple[int, float]]:
    """(global size of the guess, rtol) of each equality solve of the walk from now on."""
    rounds: list[tuple[int, float]] = []
    # the class's method, so that a second recording does not wrap the first
    solve = functools.partial(SparsePolish._equality_solution, polisher)

    def recording(active, rtol):
        rounds.append((problem.comm.allreduce(int(active.sum()), op=MPI.SUM), rtol))
        return solve(active, rtol)

    monkeypatch.setattr(polisher, "_equality_solution", recording)
    return rounds


def _plain_and_shedding_walks(monkeypatch, problem):
    """(result, rounds) of the multigrid path's solve with the walk's plain steps
    (SHED_FACTOR = 1), then with the shedding: each polished at iteration 2."""
    import admm_dolfinx.admm.polish_sparse as sparse_module

    assert sparse_module.SHED_FACTOR > 1.0
    runs = []
    for factor in (1.0, sparse_module.SHED_FACTOR):
        monkeypatch.setattr(sparse_module, "SHED_FACTOR", factor)
        with ADMMSolver(problem, step1="iterative") as solver:
            rounds = _record_rounds(monkeypatch, problem, solver.polisher)
            result = solver.solve()
        assert result.converged and result.polish.polished_at == 2
        runs.append((result, rounds))
    return runs


def _same_answer(problem, plain, shed) -> None:
    contact = _global(problem, plain.multiplier > 0)
    assert contact.any() and np.array_equal(_global(problem, shed.multiplier > 0), contact)
    u = _global(problem, plain.u.x.petsc_vec.array)
    assert rel_diff(_global(problem, shed.u.x.petsc_vec.array), u) <= 1e-8


def test_a_guess_too_large_sheds_twice_its_rim_until_it_overshoots(monkeypatch):
    """A coarse round of the multigrid walk that only sheds nodes (λ < 0 on the rim of
    a guess too large) sheds as many again, those with the least λ, until a round
    after such a one has nodes to join. The walk then takes fewer rounds than the
    plain primal-dual steps (SHED_FACTOR = 1), to the same answer, on any partition."""
    problem = hertz_sphere(level=1).problem()
    (plain, plain_rounds), (shed, shed_rounds) = _plain_and_shedding_walks(monkeypatch, problem)
    # the plain walk shrinks a guess too large over several rounds; shedding fewer
    assert shed.polish.rounds < plain.polish.rounds

    def shrinking(rounds):
        return [a - b for (a, _), (b, _) in itertools.pairwise(rounds) if a > b]

    rims, first_shed = shrinking(plain_rounds), shrinking(shed_rounds)
    # both walks reach the same guess too large first: shedding sheds up to twice its
    # rim (fewer where λ ties at the threshold, or the cap or the hold stops it)
    assert len(rims) >= 4 and rims[0] < first_shed[0] <= 2 * rims[0]
    _same_answer(problem, plain, shed)


def test_a_guess_too_large_stays_coarse_while_it_sheds(monkeypatch):
    """The coarse rounds end where a round moves few of the guess's nodes, unless the
    round sheds the rim of a guess too large: a rim of few nodes (a coarse mesh far
    from the zone) does not mean the set is near its answer. With COARSE_MOVES = 1
    (every round "few"), the plain steps turn exact after the first shedding round;
    the shedding walk stays coarse until it overshoots, and gives the same answer."""
    import admm_dolfinx.admm.polish_sparse as sparse_module

    monkeypatch.setattr(sparse_module, "COARSE_MOVES", 1.0)
    problem = hertz_sphere(level=1).problem()
    (plain, plain_rounds), (shed, shed_rounds) = _plain_and_shedding_walks(monkeypatch, problem)
    plain_coarse = [rtol == sparse_module.COARSE_RTOL for _, rtol in plain_rounds]
    shed_coarse = [rtol == sparse_module.COARSE_RTOL for _, rtol in shed_rounds]
    # the first round joins (coarse); the second sheds a rim of fewer than its nodes
    assert plain_coarse[:3] == [True, True, False] and not any(plain_coarse[2:])
    assert all(shed_coarse[:4]) and not shed_coarse[-1]
    _same_answer(problem, plain, shed)


def test_a_guess_slightly_too_large_takes_the_plain_steps(monkeypatch):
    """A first guess a ring too large (a warm start's) sheds its rim only: the
    shedding waits for a round that joins nodes (a guess too small, whose step is
    too large). The walk's sets are those of the plain steps, to the exact set."""
    import admm_dolfinx.admm.polish_sparse as sparse_module

    problem = hertz_sphere(level=1).problem()
    with ADMMSolver(problem, step1="iterative") as solver:
        lam = solver.solve().multiplier
        exact = lam > 0.0
        gap = problem.contact.gap
        # the exact set and the free nodes of Γ_C nearest the obstacle, a fifth as many
        free_gaps = np.sort(_global(problem, gap[~exact & np.isfinite(gap)]))
        count = problem.comm.allreduce(int(exact.sum()), op=MPI.SUM)
        guess = exact | (~exact & (gap <= free_gaps[count // 5]))
        walks = []
        for factor in (1.0, sparse_module.SHED_FACTOR):
            monkeypatch.setattr(sparse_module, "SHED_FACTOR", factor)
            solver.polisher.reset()
            rounds = _record_rounds(monkeypatch, problem, solver.polisher)
            outcome = solver.polisher.attempt(lam, lam, np.where(guess, 1.0, 0.0))
            assert outcome is not None
            walks.append(([size for size, _ in rounds], outcome[1] > 0.0))
    (plain, plain_set), (shed, shed_set) = walks
    assert plain[0] > count and plain[1] < plain[0]  # it shed a rim
    assert shed == plain
    for walked in (plain_set, shed_set):
        assert np.array_equal(_global(problem, walked), _global(problem, exact))


def test_a_guess_that_drops_nodes_starts_from_the_last_displacement():
    """Each multigrid solve of the walk starts from the last guess's displacement u,
    its new active normal components replaced by the prescribed ones. Started from w
    instead (u less the last guess's prescribed part), the nodes that leave 𝒜 lost
    their displacement and the start's residual exceeded the zero start's."""
    from admm_dolfinx.linalg.petsc import iterative_options

    problem = hertz_sphere(level=1).problem()
    with ADMMSolver(problem) as solver:
        lam = solver.solve().multiplier
    exact = lam > 0.0
    # the guess without the tenth of the contact zone that carries the least pressure
    pressures = _global(problem, lam[exact])
    shrunk = exact & (lam > np.quantile(pressures, 0.1))
    polisher = SparsePolish(problem, "test_start_", iterative_options(None))
    try:

        def first_residual(active):
            ksp = polisher._factorisation()
            ksp.setConvergenceHistory()
            polisher._equality_solution(active, polisher.solve_rtol)
            return ksp.getConvergenceHistory()[0]

        polisher._equality_solution(shrunk, polisher.solve_rtol)  # sets the solver up
        assert polisher._start is not None
        polisher._start.set(0.0)
        zero_start = first_residual(shrunk)  # ‖b‖
        polisher._equality_solution(exact, polisher.solve_rtol)
        from_exact = first_residual(shrunk)
    finally:
        polisher.destroy()
    assert from_exact < 0.25 * zero_start


def test_a_new_kkt_tol_reaches_the_multigrid_polish():
    """update_settings(kkt_tol) ties the walk's solves to the new tolerance, so the
    polished answer meets it (they were left at the first tolerance's accuracy)."""
    problem = hertz_sphere(level=1).problem()
    with ADMMSolver(problem, step1="iterative") as solver:
        first = solver.polisher.solve_rtol
        tighter = solver.settings.kkt_tol / 100
        solver.update_settings(rtol=tighter, expert={"kkt_tol": tighter})
        assert solver.polisher.solve_rtol == pytest.approx(first / 100)
        result = solver.solve()
    assert result.converged and result.polish.polished_at == 2
    assert result.kkt.max() <= solver.settings.kkt_tol


def test_a_guess_that_does_not_hold_a_floating_body_is_skipped():
    """An empty guess (the first iterates of a body with clearance everywhere) leaves a
    floating body's Â singular: the multigrid walk skips it instead of failing, on
    every rank alike, and walks from a guess that holds the body."""
    from admm_dolfinx.linalg.petsc import iterative_options

    problem = hertz_sphere(level=0).problem()
    with ADMMSolver(problem) as solver:
        lam = solver.solve().multiplier
    polisher = SparsePolish(problem, "test_hold_", iterative_options(None))
    try:
        nothing = np.zeros_like(lam)
        assert not polisher._holds(nothing > 0.0) and polisher._holds(lam > 0.0)
        polisher.reset()
        assert polisher.attempt(nothing, nothing, nothing) is None
        assert polisher.rounds == 0  # no solve with the singular Â
        exact = polisher.attempt(nothing, nothing, lam)
        assert exact is not None
        assert rel_diff(_global(problem, exact[1]), _global(problem, lam)) <= 1e-6
    finally:
        polisher.destroy()


def test_the_compliance_from_the_inverse_block_sums_node_by_node():
    """Wᵀ B W by node sums equals the dense product, with nodes that have no dof in C."""
    from admm_dolfinx.admm.polish_dense import _congruence

    rng = np.random.default_rng(3)
    m, c = 40, 100
    weights = np.zeros((c, m))
    node = np.sort(rng.integers(0, m - 3, c))  # the last nodes own no dof of C
    weights[np.arange(c), node] = rng.standard_normal(c)
    block = rng.standard_normal((c, c))
    block = block + block.T
    dense = weights.T @ block @ weights
    assert np.abs(_congruence(block, weights) - dense).max() <= 1e-13 * np.abs(dense).max()


def test_the_contact_space_admm_makes_the_full_admms_iterates():
    """ŷ = t + T M^{½}(r p − λ) is step 1 on Γ_C: from the same state, k iterations of
    the dense contact-space ADMM equal k iterations of the full ADMM (factorised step 1,
    the same r and α, no Anderson), to round-off. Checked against the solver's own
    iterates, recorded by its callback."""
    if MPI.COMM_WORLD.size > 1:
        pytest.skip("the dense T lives on rank 0; the solver paths are tested on 2 ranks")
    problem = example1(h=1 / 16).problem()
    k = 6
    expert = {"anderson": 0, "alpha": 1.6}
    with ADMMSolver(problem, polish=True, expert=expert) as polished:
        r, polisher = polished.penalty, polished.polisher
        sq, T, gap = polisher._sqrt_mass, polisher._compliance, problem.contact.gap
    states = []

    def record(iteration, u, lam):
        states.append((problem.apply_normal(u), lam.copy()))
        return iteration == k + 1

    with ADMMSolver(problem, penalty=r, polish=False, expert=expert) as solver:
        solver.solve(callback=record)
    # the state after iteration 1: λ¹ and p¹ = min(α N u¹ + (1 − α) p⁰ + λ⁰/r, g)
    nu1, lam1 = states[0]
    p1 = np.minimum(1.6 * nu1 + (1.0 - 1.6) * np.minimum(0.0, gap), gap)
    # t from iteration 2's step 1: N u² = M^{-½}(t + T M^{½}(r p¹ − λ¹))
    t = sq * states[1][0] - T @ (sq * (r * p1 - lam1))
    _, lam, iterations = polish_module.contact_space_admm(
        T, t, sq, gap, r, p1, lam1, stable=None, max_iterations=k
    )
    assert iterations == k
    assert rel_diff(lam, states[k][1]) <= 1e-9


@pytest.mark.parametrize("level", [1, 2])
def test_a_floating_body_is_polished_at_the_second_iteration(level):
    """Refined on Γ_C first, the guess of a body held by the contact alone is good at
    once: the default needs two iterations (one to find t, one to check the polished
    state; ``python benchmarks/polish_3d.py --scene hertz_sphere`` counts them against
    the walk alone), and the answer is exact."""
    problem = hertz_sphere(level=level).problem()
    with ADMMSolver(problem) as solver:
        result = solver.solve()
    assert result.polish.polished_at == result.iterations == 2
    assert result.kkt.max() <= 1e-10
    with ADMMSolver(problem, polish=False, rtol=1e-11, max_iter=3000) as solver:
        tight = solver.solve()
    assert rel_diff(_global(problem, result.multiplier), _global(problem, tight.multiplier)) <= 1e-8
