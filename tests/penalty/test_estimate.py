"""r* against a dense reference (numpy/scipy), floating bodies, and factorisation reuse."""

import numpy as np
import pytest
from mpi4py import MPI
from petsc4py import PETSc

from admm_dolfinx import ADMMSolver, estimate_penalty
from admm_dolfinx.scenes.library import example1, example2, example3, hertz_sphere

from dense_reference import algorithm5_eigenvalues, rotated_pencil_eigenvalues

serial_only = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="dense reference is serial")

TIGHT = 1e-10


def _compare(est, lmin, lmax, rel):
    r_ref = 1.0 / np.sqrt(lmin * lmax)
    assert est.lambda_min == pytest.approx(lmin, rel=rel)
    assert est.lambda_max == pytest.approx(lmax, rel=rel)
    assert est.r == pytest.approx(r_ref, rel=rel)


@serial_only
@pytest.mark.parametrize("h", [1 / 8, 1 / 16, 1 / 32, 1 / 64])
def test_example1_against_algorithm5(h):
    problem = example1(h=h).problem()
    ev = algorithm5_eigenvalues(problem)
    assert ev.size == problem.num_contact_nodes
    dense = estimate_penalty(problem)  # 2D default: dense, from the condensed factorisation
    assert dense.details["method"] == "dense"
    _compare(dense, ev[0], ev[-1], 1e-9)
    _compare(estimate_penalty(problem, tol=TIGHT, method="factorised"), ev[0], ev[-1], 1e-6)
    loose = estimate_penalty(problem, method="local")  # default tolerance
    _compare(loose, ev[0], ev[-1], 0.05)
    assert loose.solves < 60


@serial_only
@pytest.mark.parametrize("level", [0, 1])
def test_example3_against_algorithm5(level):
    problem = example3(level=level).problem(contact_normal="body")
    ev = algorithm5_eigenvalues(problem)
    _compare(estimate_penalty(problem, tol=TIGHT), ev[0], ev[-1], 1e-6)
    loose = estimate_penalty(problem)
    _compare(loose, ev[0], ev[-1], 0.05)
    # λ_max by multigrid, LOBPCG started near the top eigenvector (trial responses from
    # CG steps): level 1 took 11 iterations from one-V-cycle responses, now 3
    assert loose.details["lambda_max_method"] == "multigrid"
    assert loose.details["lobpcg_iterations"] <= 6


def _layer_scene(scene):
    """Example 3 (level 1) or a mesh graded towards Γ_C, and its dense λ_min."""
    if scene == "graded":
        problem = example3(level=0, h_bottom=0.06, h_top=0.6).problem(contact_normal="body")
    else:
        problem = example3(level=1).problem(contact_normal="body")
    return problem, algorithm5_eigenvalues(problem)[0]


@serial_only
@pytest.mark.parametrize("scene", ["example3", "graded"])
def test_layers_stop_at_the_tolerance_asked(scene):
    """λ_min's layers (local method) grow until two agree to ``lambda_min_tol``, and
    the last one's value is then within that tolerance of the whole body's λ_min
    (the dense pencil): the truncation error at least halves per doubling of the
    layer. A looser tolerance stops at fewer rings, never more; on Example 3 and on
    a mesh graded towards Γ_C (elements 10x smaller on Γ_C than on the top face)
    both stop within 4 rings."""
    problem, exact = _layer_scene(scene)
    rings = []
    for lambda_min_tol in (0.02, 0.1):
        est = estimate_penalty(problem, method="local", lambda_min_tol=lambda_min_tol)
        assert est.details["lambda_min_tol"] == lambda_min_tol
        assert est.details["layer_steps"] >= 2  # an agreement needs two layers
        assert est.lambda_min <= exact * (1 + 1e-3)  # a layer is stiffer than the body
        assert est.lambda_min == pytest.approx(exact, rel=lambda_min_tol)
        rings.append(est.details["layers"])
    assert rings[1] <= rings[0] <= 4
    assert estimate_penalty(problem, method="local").details["lambda_min_tol"] == 0.02
    with pytest.raises(ValueError, match="lambda_min_tol"):
        estimate_penalty(problem, method="local", lambda_min_tol=1.0)


@serial_only
@pytest.mark.parametrize("scene", ["example3", "graded"])
def test_fixed_rings_take_one_layer(scene):
    """``lambda_min_rings`` computes λ_min on that one layer, with no growth check: a
    lower bound of the whole body's λ_min (a layer is stiffer), closer with more
    rings (the Schur complements decrease to the body's). Zero rings are the contact
    nodes alone (the rest held fixed), the layer the solver's surface metric uses for
    β: one factorisation of a surface problem where growth needs two of volume layers."""
    problem, exact = _layer_scene(scene)
    values = []
    for rings in (0, 1, 2):
        est = estimate_penalty(problem, method="local", lambda_min_rings=rings)
        assert est.details["layers"] == rings and est.details["layer_steps"] == 1
        assert est.details["lambda_min_rings"] == rings
        values.append(est.lambda_min)
    assert values[0] < values[1] * (1 + 1e-3)  # S_0 ≥ S_1 ≥ S_2 ≥ S
    assert values[1] < values[2] * (1 + 1e-3)
    assert values[2] <= exact * (1 + 1e-3)
    assert values[0] > 0.4 * exact  # the contact nodes alone: within a small factor
    # growth from ring 1 to the 10 % agreement passes through ring 2 (or further)
    grown = estimate_penalty(problem, method="local", lambda_min_tol=0.1)
    assert grown.details["layer_steps"] >= 2
    assert values[2] < grown.lambda_min * (1 + 1e-3)
    with ADMMSolver(problem) as solver:  # the 3D default: surface metric, local r*
        assert solver.surface_penalty is not None
        used = solver.penalty_estimate
        assert used.details["layers"] == 0 and used.details["layer_steps"] == 1
        assert used.lambda_min == pytest.approx(values[0], rel=1e-2)
        details = solver.surface_penalty.details
        assert details["layers"] == 0 and "mu_max_layer" in details  # a layer was solved
    for bad in (-1, 1.5, True):
        with pytest.raises(ValueError, match="lambda_min_rings"):
            estimate_penalty(problem, method="local", lambda_min_rings=bad)
    with pytest.raises(ValueError, match="give one of them"):
        estimate_penalty(problem, method="local", lambda_min_rings=1, lambda_min_tol=0.1)


@serial_only
def test_rotated_reference_agrees_with_algorithm5():
    """The general (rotated) dense reference reproduces the literal Algorithm 5."""
    problem = example1(h=1 / 8).problem()
    np.testing.assert_allclose(
        rotated_pencil_eigenvalues(problem), algorithm5_eigenvalues(problem), rtol=1e-9
    )


@pytest.mark.parametrize("scene", ["cylinder", "sphere"])
def test_the_floating_motions_as_vectors(scene):
    """RigidMotions.vectors: motions A does not resist (A d = 0, Dirichlet dofs
    included) whose normal parts at the contact nodes are the analysis's N d, on
    any partition."""
    problem = (example2(level=0) if scene == "cylinder" else hertz_sphere(level=0)).problem()
    motions = problem.rigid_motions.vectors(problem.V)
    try:
        assert len(motions) == problem.rigid_motions.floating == 1
        for d, normal in zip(motions, problem.rigid_motions.normal_motion, strict=True):
            work = problem.A.createVecLeft()
            try:
                problem.A.mult(d, work)
                assert work.norm() <= 1e-10 * problem.stiffness_scale * d.norm()
            finally:
                work.destroy()
            np.testing.assert_allclose(problem.apply_normal(d), normal, atol=1e-12)
            # Γ_C sees it: the vertical translation, normal to the plane at every node
            size = d.norm(PETSc.NormType.NORM_INFINITY)
            assert problem.global_norm(normal, np.inf) == pytest.approx(size, rel=1e-12)
    finally:
        for d in motions:
            d.destroy()


@serial_only
@pytest.mark.parametrize("level", [0, 1])
def test_floating_curved_body(level):
    """Hertz quarter cylinder: curved Γ_C and a free vertical translation (A singular)."""
    problem = example2(level=level).problem()
    lam = rotated_pencil_eigenvalues(problem)
    assert np.isinf(lam[-1]) and np.isfinite(lam[-2])  # exactly one rigid mode seen by Γ_C
    dense = estimate_penalty(problem)
    assert dense.details["method"] == "dense" and dense.details["rigid_modes"] == 1
    _compare(dense, lam[0], lam[-2], 1e-9)
    assert problem.rigid_motions.floating == 1  # what the dense r* deflates
    est = estimate_penalty(problem, tol=TIGHT, method="factorised")
    assert est.details["rigid_modes"] == 1
    _compare(est, lam[0], lam[-2], 1e-6)
    loose = estimate_penalty(problem, method="local")
    _compare(loose, lam[0], lam[-2], 0.05)
    # the multigrid λ_max does not apply to a floating body: it falls back, and says so
    assert loose.details["lambda_max_method"] == "factorised"
    # and the ADMM converges at that r, held only by the contact
    with ADMMSolver(problem, penalty=est.r) as solver:
        result = solver.solve()
    assert result.kkt.max() < 1e-4
    assert result.num_active > 0


def _cholesky_counts():
    sym, num = PETSc.Log.Event("MatCholFctrSym"), PETSc.Log.Event("MatCholFctrNum")
    return sym.getPerfInfo()["count"], num.getPerfInfo()["count"]


def test_auto_penalty_2d_factorises_the_body_once():
    """2D, one process: one sparse factorisation (A condensed onto Γ_C) gives r* and
    serves every ADMM step at r*; under MPI the ADMM factorises A + r*K besides."""
    problem = example1(h=1 / 16).problem()
    sym0, num0 = _cholesky_counts()
    with ADMMSolver(problem) as solver:
        result = solver.solve()
        estimate = solver.penalty_estimate
        operator = type(solver.operator).__name__
    sym1, num1 = _cholesky_counts()
    assert estimate.details["method"] == "dense" and result.penalty == estimate.r
    serial = problem.comm.size == 1
    assert operator == ("CondensedOperator" if serial else "PenalisedOperator")
    assert (sym1 - sym0, num1 - num0) == ((1, 1) if serial else (2, 2))
    if not serial:  # the condensed factorisation that serves r* (and polishing) is r*'s cost
        assert result.timings["penalty"] > estimate.time


@pytest.mark.parametrize("metric", ["mass", "surface"])
@pytest.mark.parametrize("method,tol", [("local", 1e-2), ("factorised", 1e-8)])
def test_auto_penalty_shares_one_symbolic_factorisation(method, tol, metric):
    """3D (iterative r*), counted from PETSc's log (Cholesky events): the whole body
    is analysed once, by its factorisation, which then serves every numeric one (the
    plan chooses step 1 from the mesh's bracket of the cost, with no analysis). With the local
    method it is factorised once, at r* (λ_max by multigrid; each layer along Γ_C adds
    one small factorisation); with the factorised one also at r_a and for the exact
    Schur complement. The surface metric (the 3D default) adds one small factorisation
    per layer of its μ_max, and for the surface QP (distributed) one symbolic
    factorisation and a numeric one per change of the contact set; it factorises the
    body at its own r, with the same symbolic analysis."""
    problem = example3(level=0).problem(contact_normal="body")
    sym0, num0 = _cholesky_counts()
    options = {"expert": {"penalty_method": method, "penalty_tol": tol, "penalty_metric": metric}}
    with ADMMSolver(problem, **options) as solver:
        result = solver.solve()
        estimate = solver.penalty_estimate
        surface = solver.surface_penalty
    sym1, num1 = _cholesky_counts()
    assert estimate is not None and estimate.details["method"] == method
    assert (surface is not None) == (metric == "surface")
    assert result.penalty == (estimate.r if surface is None else surface.r)
    steps = estimate.details["layer_steps"]
    extra_sym = extra_num = 1 if surface else 0  # the layer of μ_max
    if surface:  # step 2's QP: one analysis, a numeric Cholesky per contact set
        qp = result.projection["factorisations"]
        assert qp > 1
        extra_sym += 1
        extra_num += qp
    assert (steps > 0) == (method == "local")
    assert solver.plan.step1_basis == "mesh"
    assert sym1 - sym0 == 1 + steps + extra_sym
    assert num1 - num0 == (1 if steps else 3) + steps + extra_num
    assert estimate.details["lambda_max_method"] == ("multigrid" if steps else "factorised")
    assert result.timings["penalty"] == pytest.approx(
        estimate.time + (surface.time if surface else 0.0), rel=1e-12
    )


@pytest.mark.parametrize("h", [1 / 16, 1 / 128])
def test_parallel_dense_estimate_matches_serial(h):
    """2D default: dense, from the condensed factorisation (computed on all ranks, S_C
    on rank 0): the same r* to round-off. At h = 1/128 (c = 256), distributed, MUMPS
    fills one triangle of S_C and leaves scratch values in the other, which must not
    be read."""
    problem = example1(h=h).problem()
    serial_problem = example1(MPI.COMM_SELF, h=h).problem()
    dense, dense_serial = estimate_penalty(problem), estimate_penalty(serial_problem)
    assert dense.details["method"] == "dense"
    assert dense.r == pytest.approx(dense_serial.r, rel=1e-10)
    assert dense.lambda_min == pytest.approx(dense_serial.lambda_min, rel=1e-10)
    assert dense.lambda_max == pytest.approx(dense_serial.lambda_max, rel=1e-10)
    serial_problem.destroy()


def test_dense_estimate_matches_serial():
    """The dense r* on all ranks against one rank: the same λ_min, λ_max to round-off
    (the dense work is on rank 0; S_C comes from all ranks)."""
    serial_problem = example1(MPI.COMM_SELF, h=1 / 64).problem()
    reference = estimate_penalty(serial_problem)
    serial_problem.destroy()
    problem = example1(h=1 / 64).problem()
    dense = estimate_penalty(problem)
    assert dense.details["method"] == "dense" and dense.details["rigid_modes"] == 0
    assert dense.lambda_min == pytest.approx(reference.lambda_min, rel=1e-10)
    assert dense.lambda_max == pytest.approx(reference.lambda_max, rel=1e-10)


def test_parallel_estimate_matches_serial():
    """The iterative method on all ranks against one rank."""
    problem = example1(h=1 / 16).problem()
    serial_problem = example1(MPI.COMM_SELF, h=1 / 16).problem()
    dense = estimate_penalty(problem)
    est = estimate_penalty(problem, tol=TIGHT, method="factorised")
    serial = estimate_penalty(serial_problem, tol=TIGHT, method="factorised")
    assert est.r == pytest.approx(serial.r, rel=1e-6)
    assert est.lambda_min == pytest.approx(serial.lambda_min, rel=1e-6)
    assert est.lambda_max == pytest.approx(serial.lambda_max, rel=1e-6)
    assert est.r == pytest.approx(dense.r, rel=1e-6)
    # default tolerance: λ_max by multigrid, whose aggregates depend on the partition;
    # LOBPCG stops at a residual of tol, so λ_max (and r*) move within its accuracy,
    # here far below tol (benchmarks/penalty_accuracy.py against the dense reference)
    loose = estimate_penalty(problem, method="local")
    loose_serial = estimate_penalty(serial_problem, method="local")
    assert loose.details["lambda_max_method"] == "multigrid"
    assert loose.r == pytest.approx(loose_serial.r, rel=2e-4)
    serial_problem.destroy()


@pytest.mark.parametrize("tol", [0.0, 1.0, -1e-3])
def test_bad_tolerance(tol):
    problem = example1(h=1 / 8, mesher="builtin").problem()
    with pytest.raises(ValueError, match="tol must lie in"):
        estimate_penalty(problem, tol=tol)


@pytest.mark.parametrize(
    "scene, expected",
    [
        (lambda: example1(h=1 / 16), 2),  # flat Γ_C: 1, x (y is constant there)
        (lambda: example2(level=0), 3),  # curved Γ_C: 1, x, y
        (lambda: example3(level=0), 3),  # flat bottom face: 1, x, y (z is constant)
    ],
)
def test_trial_pressures_drop_dependent_ones(scene, expected):
    """λ_max's start solves only for affine pressures independent on Γ_C (MPI-safe)."""
    from admm_dolfinx.linalg.contact_space import ContactSpace
    from admm_dolfinx.penalty.lambda_max import affine_pressure_loads

    problem = scene().problem()
    space = ContactSpace(problem)
    loads = affine_pressure_loads(space)
    try:
        assert len(loads) == expected
        gram = np.array([[a.dot(b) for b in loads] for a in loads])  # global dots
        eigenvalues = np.linalg.eigvalsh(gram)
        assert eigenvalues[0] > 1e-6 * eigenvalues[-1]  # independent, none near zero
    finally:
        for vec in loads:
            vec.destroy()
        space.destroy()


class _AlternatingSign:
    """An indefinite preconditioner, +x and −x on alternate calls: the sign of CG's
    (r, Pr) changes between its first two steps, which PETSc reports as a breakdown
    (DIVERGED_INDEFINITE_PC) however many steps the start plans (two or more)."""

    def __init__(self):
        self.calls = 0

    def apply(self, pc, x, y):
        x.copy(y)
        self.calls += 1
        if self.calls % 2 == 0:
            y.scale(-1.0)


def test_ritz_start_falls_back_when_cg_breaks_down():
    """When the start's CG really breaks down (an indefinite preconditioner, not just the
    planned steps taken), each response is one preconditioner application instead: the
    Ritz vectors are finite, B-orthonormal and lie in span{P f_i} = span{f_i}."""
    from admm_dolfinx.linalg.contact_space import ContactSpace
    from admm_dolfinx.penalty.lambda_max import (
        BLOCK_SIZE,
        _ritz_start,
        affine_pressure_loads,
        gram_matrix,
    )

    problem = example1(h=1 / 16).problem()
    space = ContactSpace(problem)
    loads = affine_pressure_loads(space)
    pc = PETSc.PC().create(comm=problem.comm)
    pc.setType(PETSc.PC.Type.PYTHON)
    pc.setPythonContext(_AlternatingSign())
    pc.setOperators(problem.A)
    start = []
    try:
        start, _ = _ritz_start(problem.K, problem.A, pc, loads, "test_breakdown_")
        assert len(start) == BLOCK_SIZE
        gram = gram_matrix(problem.A, start)
        assert np.all(np.isfinite(gram))
        np.testing.assert_allclose(gram, np.eye(BLOCK_SIZE), atol=1e-10)
        basis = np.array([[a.dot(b) for b in loads] for a in loads])
        for vec in start:  # the part of vec outside span{P f_i} vanishes
            coefficients = np.linalg.solve(basis, [f.dot(vec) for f in loads])
            residual = vec.copy()
            residual.maxpy(-coefficients, loads)
            assert residual.norm() <= 1e-10 * vec.norm()
            residual.destroy()
    finally:
        for vec in (*start, *loads):
            vec.destroy()
        pc.destroy()
        space.destroy()


def test_iterative_method_with_a_condensed_operator_uses_its_own():
    """method="local" with the solver's condensed operator: iterative, not dense."""
    from admm_dolfinx.operators.condensed import CondensedOperator

    problem = example1(h=1 / 16).problem()
    condensed = CondensedOperator(problem, "test_shared_")
    try:
        shared = estimate_penalty(problem, operator=condensed)
        iterative = estimate_penalty(problem, operator=condensed, method="local")
    finally:
        condensed.destroy()
    assert shared.details["method"] == "dense"
    assert iterative.details["method"] in ("local", "factorised")
    assert iterative.r == pytest.approx(shared.r, rel=0.05)


@pytest.mark.parametrize("rigid", [0, 1, 6])
@pytest.mark.parametrize("known", [True, False])
def test_dense_ends_against_eigvalsh(rigid, known):
    """The dense r* on a synthetic pencil (curved-like W: c > m) with up to 6 rigid
    modes, given (deflated) or found by their θ = 1/r_a: the same λ_min, λ_max and
    rigid count as numpy's eigvalsh of the pencil."""
    from admm_dolfinx.penalty import dense as dense_pencil

    rng = np.random.default_rng(7 + rigid)
    m, c = 450, 600  # W: c × m of full column rank, as for curved Γ_C
    q, _ = np.linalg.qr(rng.standard_normal((c, c)))
    spectrum = np.concatenate([np.zeros(rigid), np.geomspace(1.0, 2e4, c - rigid)])
    schur = (q * spectrum) @ q.T
    schur = 0.5 * (schur + schur.T)
    weights = rng.standard_normal((c, m))
    k_cc = weights @ weights.T
    # reference: every eigenvalue θ of T(r_a) by numpy, mapped to λ = θ/(1 − r_a θ)
    r_a = 1e-3 * np.trace(schur) / np.trace(k_cc)
    theta = np.linalg.eigvalsh(dense_pencil.compliance_matrix(schur, k_cc, weights, r_a))
    finite = theta[1.0 - r_a * theta > dense_pencil.RIGID_TOL]
    lam = finite / (1.0 - r_a * finite)
    assert theta.size - finite.size == rigid
    # the rigid directions in compliance coordinates: Wᵀz for z in the kernel of S_C
    directions = weights.T @ q[:, :rigid] if known else None
    lam_min, lam_max, count = dense_pencil.extremes_from_schur(
        schur, k_cc, weights, rigid=directions
    )
    assert count == rigid
    assert lam_min == pytest.approx(lam[0], rel=1e-9)
    assert lam_max == pytest.approx(lam[-1], rel=1e-9)


def test_dense_failure_is_a_clear_error_on_every_rank(monkeypatch):
    """A failure of the dense work on rank 0 is a RuntimeError on every rank, not a hang."""
    from admm_dolfinx.penalty import dense as dense_pencil

    problem = example1(h=1 / 32).problem()

    def broken(*args, **kwargs):
        raise np.linalg.LinAlgError("a broken LAPACK")

    if MPI.COMM_WORLD.rank == 0:  # rank 0 alone does the dense work
        monkeypatch.setattr(dense_pencil, "compliance_matrix", broken)
    with pytest.raises(RuntimeError, match=r"dense r.*broken LAPACK"):
        estimate_penalty(problem)
    monkeypatch.undo()
    assert estimate_penalty(problem).details["method"] == "dense"


@serial_only
@pytest.mark.parametrize(
    "scene",
    [
        lambda: example1(h=1 / 16, mesher="builtin"),  # m = 32: EPSLAPACK
        lambda: example1(h=1 / 256, mesher="builtin"),  # m = 512 > LAPACK_LIMIT: Krylov–Schur
        lambda: example2(level=1),  # floating: the rigid motion deflated
    ],
    ids=["lapack", "krylov-schur", "floating"],
)
def test_dense_r_star_comes_from_slepc_and_equals_numpys(scene, monkeypatch):
    """The 2D r* is SLEPc's (an EPS on the dense compliance), the same to 1e-10 as the
    whole spectrum by numpy's LAPACK (the dense method before SLEPc)."""
    from admm_dolfinx.penalty import dense as dense_pencil

    problem = scene().problem()
    calls = []
    real = dense_pencil.compliance_spectrum

    def counted(compliance, prefix, *, whole):
        calls.append((compliance.shape[0], prefix))
        return real(compliance, prefix, whole=whole)

    monkeypatch.setattr(dense_pencil, "compliance_spectrum", counted)
    slepc = estimate_penalty(problem, petsc_options_prefix="mine_")
    assert slepc.details["method"] == "dense" and calls
    assert all(prefix == "mine_dense_" for _, prefix in calls)
    monkeypatch.setattr(
        dense_pencil, "compliance_spectrum", lambda t, prefix, whole: np.linalg.eigvalsh(t)
    )
    reference = estimate_penalty(problem)
    assert slepc.r == pytest.approx(reference.r, rel=1e-10)
    assert slepc.lambda_min == pytest.approx(reference.lambda_min, rel=2e-10)
    assert slepc.lambda_max == pytest.approx(reference.lambda_max, rel=2e-10)


@serial_only
def test_dense_eigensolver_reads_its_options_prefix():
    """The EPS of the dense r* takes the user's options under <prefix>penalty_dense_."""
    problem = example1(h=1 / 16, mesher="builtin").problem()
    options = PETSc.Options()
    options["admm_penalty_dense_eps_type"] = "no_such_type"
    try:
        with pytest.raises(RuntimeError, match="admm_penalty_dense_"):
            ADMMSolver(problem)
    finally:
        del options["admm_penalty_dense_eps_type"]
    assert ADMMSolver(problem).solve().converged
