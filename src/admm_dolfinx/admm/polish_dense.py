"""Active-set polishing: the exact solution once ADMM has found where the body touches.

Given the set 𝒜 of contact nodes that touch, the contact problem is an equality-
constrained quadratic programme, whose solution is one linear solve away. With the
dense Schur complement S_C of A onto the contact dofs (what
:class:`~admm_dolfinx.operators.condensed.CondensedOperator` computes in 2D, and what the r*
estimate uses) that solve reduces to an m × m dense system on Γ_C, and the ADMM
state (p, λ) it gives is a fixed point of the ADMM map: one more step-1 solve with the
stored factors returns the displacement.

Derivation. Let T = Wᵀ (S_C + r K_CC)⁻¹ W be the compliance of Γ_C at the penalty r
(W = Nᵀ M^{½} on C), and ŷ = M^{½} N u. A step-1 solve from the state (p, λ) gives
ŷ = t + T M^{½} q with q = r p − λ and t the (unknown) response to the load alone; so
one iterate (N u, q) determines t = M^{½} N u − T M^{½} q. Eliminating the interior
from A u − f + NᵀMλ = 0 with λ = 0 off 𝒜 and (N u)_𝒜 = g_𝒜 leaves

    (I − rT) ŷ + T M^{½} λ = t,      ŷ_𝒜 = M^{½}_𝒜 g_𝒜,

m equations for the unknowns ŷ off 𝒜 and λ on 𝒜 (Dirichlet values included: they
enter t). The condition number of this system is about √κ, κ the condition number of
the contact pencil.

The guess 𝒜 = {λ⁺ > 0} comes from the ADMM iterate. It is corrected by
primal-dual active-set steps (nodes with λ < 0 leave 𝒜, nodes that penetrate join it),
at most ``polish_rounds`` new ones per attempt (the solver's setting;
:data:`MAX_ROUNDS` by default). The outcome depends on 𝒜 alone, so each correction
is computed once per solve and an attempt that joins an earlier walk goes on where
it stopped (:mod:`admm_dolfinx.admm.active_set`). An empty guess (the first iterates, before ADMM
predicts any contact) starts from the unconstrained solution: its penetrating nodes
join first. For a floating body that system is singular.

Before the walk, the guess is refined *in the contact space*, so that a guess the
walk could not start from (a floating body that it does not hold: a singular system)
or that would take many rounds (a contact zone that ADMM builds a few nodes per
iteration) becomes a good one. With T at hand, ADMM's own iteration restricted to Γ_C is

    ŷ = t + T M^{½} (r p − λ),   then steps 2–3 on N u = M^{-½} ŷ,

m × m dense work per iteration (no step-1 solve), the same iterates as the full ADMM
at the same r. It runs (over-relaxed, :data:`INNER_ALPHA`) from the current λ⁺ until
its active set has not changed for :data:`INNER_STABLE` iterations, at most
:data:`INNER_MAX_ITERATIONS`, and the walk starts from that set. Only a state
that satisfies every sign condition is returned; the ADMM loop then evaluates it like
any other proposal (safeguard and stopping test), so a polished result meets the same
test as any other. ``python benchmarks/polish_3d.py --scene hertz_sphere`` measures the
iterations it saves.

The dense work is done on rank 0 (the nodal values are gathered there, the result is
scattered back), so the polished state is the same on any number of processes to
round-off. Each round costs O(m³): where that is large against the step-1 solves
(thousands of contact nodes), attempts are skipped while polishing has taken longer
than the rest of the iterations, so it costs about as much as they do at most. That
decision depends on measured times; where it never binds (the paper's meshes, whose
dense work takes milliseconds) the iteration is deterministic.
"""

from __future__ import annotations

import math
import time

import numpy as np
import numpy.typing as npt

from admm_dolfinx._logging import get_logger
from admm_dolfinx._mpi import RankLayout, collective_call, from_rank0
from admm_dolfinx.admm.active_set import ActiveSetWalk
from admm_dolfinx.linalg.mumps_schur import inverse_block
from admm_dolfinx.operators.condensed import ContactSupport
from admm_dolfinx.penalty.dense import compliance_matrix
from admm_dolfinx.problem.contact_problem import ContactProblem

__all__ = ["MAX_ROUNDS", "ActiveSetPolish", "contact_space_admm"]

logger = get_logger(__name__)

#: Primal-dual active-set corrections of one guess, by default (``polish_rounds``).
MAX_ROUNDS = 10
#: Relative tolerance of the sign conditions (λ ≥ 0 on 𝒜, N u ≤ g off it): round-off
#: of the dense solve, far below any stopping tolerance.
SIGN_TOL = 1e-10
#: The contact-space ADMM that refines every guess before its walk: over-relaxation (the accelerated
#: preset's), the iterations its active set must stay unchanged, the relative change
#: of p below which it may stop, and its iteration cap (each costs O(m²)).
INNER_ALPHA = 1.6
INNER_STABLE = 20
INNER_CHANGE = 1e-4
INNER_MAX_ITERATIONS = 5000


class ActiveSetPolish:
    """Exact solutions for guessed active sets, from the dense Schur complement S_C.

    Args:
        problem: The contact problem.
        schur: S_C on rank 0 (None elsewhere).
        k_cc: K = NᵀMN on C × C, rank 0.
        weights: W = Nᵀ M^{½} on C (c × m), rank 0.

    Attributes:
        attempts: Guesses tried since :meth:`reset`.
        rounds: Dense solves since :meth:`reset`.
        setup_time: Seconds of the last :meth:`set_penalty` (T = Wᵀ(S_C + rK_CC)⁻¹W).
        skipped: Attempts skipped for time since :meth:`reset`.
        time: Seconds spent since :meth:`reset` (all ranks wait for rank 0).
    """

    def __init__(
        self,
        problem: ContactProblem,
        schur: npt.NDArray[np.float64] | None,
        k_cc: npt.NDArray[np.float64] | None,
        weights: npt.NDArray[np.float64] | None,
        rounds: int = MAX_ROUNDS,
    ):
        self.comm = problem.comm
        #: Primal-dual active-set corrections per guess.
        self.max_rounds = int(rounds)
        self.problem = problem
        self._schur, self._k_cc, self._weights = schur, k_cc, weights
        self._layout = RankLayout(self.comm, problem.contact.gap.size)
        self._sqrt_mass = self._layout.gather(np.sqrt(problem.contact.mass))
        self.penalty = float("nan")
        self.setup_time = 0.0
        self._compliance: npt.NDArray[np.float64] | None = None
        self._shifted: npt.NDArray[np.float64] | None = None
        self._gap: npt.NDArray[np.float64] | None = None
        self._walk: ActiveSetWalk[tuple] = ActiveSetWalk(lambda active: active.tobytes())
        self.attempts = self.rounds = self.skipped = 0
        #: Iterations of the contact-space ADMM since :meth:`reset` (rank 0).
        self.inner_iterations = 0
        self.time = 0.0
        # with from_factors: step 1's operator, whose factors give T, and C's dofs
        self._factors = None
        self._dofs: npt.NDArray[np.integer] | None = None

    def destroy(self) -> None:
        """Nothing to free (the dense arrays are NumPy's)."""

    @classmethod
    def from_operator(
        cls, problem: ContactProblem, operator, rounds: int = MAX_ROUNDS
    ) -> ActiveSetPolish:
        """From a :class:`~admm_dolfinx.operators.condensed.CondensedOperator`.

        The arrays outlive the operator.
        """
        return cls(problem, operator.schur, operator.k_cc, operator.support.weights, rounds)

    @classmethod
    def from_factors(
        cls, problem: ContactProblem, operator, rounds: int = MAX_ROUNDS
    ) -> ActiveSetPolish:
        """From the MUMPS factors of step 1's A + rK (a factorised step 1).

        T = Wᵀ [(A + rK)⁻¹]_CC W is read off the factors that step 1 already has, by
        MUMPS's selected entries of the inverse
        (:func:`~admm_dolfinx.linalg.mumps_schur.inverse_block`), at every penalty
        that step 1 is factorised at: no Schur complement is computed.

        Args:
            problem: The contact problem.
            operator: Step 1's :class:`~admm_dolfinx.operators.penalised.PenalisedOperator`
                (its :meth:`set_penalty` is called before this polisher's; under MPI
                factorised with
                :data:`~admm_dolfinx.linalg.mumps_schur.CENTRALISED_RHS`).
            rounds: Primal-dual active-set corrections per guess.
        """
        support = ContactSupport.build(problem)
        polish = cls(problem, None, None, support.weights, rounds)
        polish._factors, polish._dofs = operator, support.dofs
        return polish

    def set_penalty(self, r: float) -> None:
        """Use the penalty r of the step-1 solves: T and I − rT on rank 0; collective.

        A set-up cost, like the factorisation (:attr:`setup_time`), not paid inside the
        iterations.
        """
        if r == self.penalty:
            return
        t0 = time.perf_counter()
        self.penalty = float(r)
        self._walk.clear()
        self._compliance = self._shifted = None
        block = None
        if self._factors is not None:  # collective: MUMPS reads (A + rK)⁻¹_CC on rank 0
            try:
                block = collective_call(
                    self.comm, lambda: self._inverse_block(r), "reading (A + rK)⁻¹_CC"
                )
            except Exception as error:  # raised on every rank alike
                logger.warning(
                    "Active-set polishing is off for this penalty: %s: %s",
                    type(error).__name__,
                    error,
                )
                self.setup_time = from_rank0(self.comm, time.perf_counter() - t0)
                return
        if self.comm.rank == 0:
            try:  # never raise on rank 0 alone: the other ranks would wait
                self._compliance = self._compliance_at(r, block)
                self._shifted = np.eye(self._compliance.shape[0]) - r * self._compliance
            except Exception as error:  # polishing is an option: the ADMM goes on without
                self._compliance = self._shifted = None
                logger.warning(
                    "Active-set polishing is off for this penalty: %s: %s",
                    type(error).__name__,
                    error,
                )
        self.setup_time = from_rank0(self.comm, time.perf_counter() - t0)

    def _inverse_block(self, r: float) -> npt.NDArray[np.float64] | None:
        """[(A + rK)⁻¹]_CC from step 1's factors (rank 0; None elsewhere); collective."""
        assert self._factors is not None and self._dofs is not None
        if self._factors.penalty != r:
            raise RuntimeError("step 1 is not factorised at this penalty.")
        return inverse_block(self._factors.ksp.getPC().getFactorMatrix(), self._dofs)

    def _compliance_at(
        self, r: float, block: npt.NDArray[np.float64] | None = None
    ) -> npt.NDArray[np.float64]:
        """T at the penalty r (rank 0): from S_C, or from the block of step 1's factors."""
        if self._factors is not None:
            if block is None or self._weights is None:
                raise RuntimeError("no block of (A + rK)⁻¹ was read.")
            return _congruence(block, self._weights)
        schur, k_cc, weights = self._dense_data()
        return compliance_matrix(schur, k_cc, weights, r)

    def _dense_data(
        self,
    ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        """S_C, K_CC and W (rank 0).

        Raises:
            RuntimeError: On a rank without them (all but rank 0).
        """
        if self._schur is None or self._k_cc is None or self._weights is None:
            raise RuntimeError("S_C, K_CC and W of the dense polish are on rank 0 only.")
        return self._schur, self._k_cc, self._weights

    def reset(self) -> None:
        """Start a solve: read the current gap; forget the walk's steps; collective."""
        self._gap = self._layout.gather(self.problem.contact.gap)
        self._walk.clear()
        self.attempts = self.rounds = self.skipped = self.inner_iterations = 0
        self.time = 0.0

    def attempt(
        self,
        normal_u: npt.NDArray[np.float64],
        force: npt.NDArray[np.float64],
        multiplier: npt.NDArray[np.float64],
        budget: float = math.inf,
    ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]] | None:
        """The exact state (p, λ) for the active set {λ⁺ > 0}, or None; collective.

        Args:
            normal_u: N u of a step-1 solve (local nodal values).
            force: Its q = r p − λ (the normal force of its right-hand side).
            multiplier: λ⁺ of the same iteration: the contact-space ADMM that refines
                the guess before the walk starts from it (with the refinement off,
                ``INNER_MAX_ITERATIONS = 0``, the guess is {λ⁺ > 0} itself).
            budget: Seconds the caller has spent otherwise (its iterations): while the
                polishing time so far exceeds it, the attempt is skipped (decided on
                rank 0), so that polishing costs about as much as the iterations at
                most.

        Returns:
            The local parts of p = min(N u, g) and λ ≥ 0 of the solution, if a
            primal-dual active-set correction of ``guess`` satisfies every sign
            condition; None otherwise.
        """
        t0 = time.perf_counter()
        data = self._layout.gather(np.stack([normal_u, force, multiplier]))
        outcome, rounds, skip = None, 0, False
        if self.comm.rank == 0:
            skip = self.time > budget
            if not skip:
                try:  # never raise on rank 0 alone: the other ranks would wait
                    assert data is not None  # gathered on rank 0
                    outcome, rounds = self._solve(data[0], data[1], data[2])
                except Exception as error:  # an attempt that fails is one not taken
                    logger.warning("Polishing attempt failed: %s: %s", type(error).__name__, error)
                    outcome, rounds = None, 1
        rounds, found, skip = from_rank0(self.comm, (rounds, outcome is not None, skip))
        self.attempts += int(rounds > 0)
        self.rounds += rounds
        self.skipped += int(skip)
        local = None
        if found:
            pair = self._layout.scatter(np.stack(outcome) if outcome is not None else None, 2)
            local = (pair[0], pair[1])
        self.time += time.perf_counter() - t0
        return local

    # ---------------------------------------------------------------- rank 0
    def _solve(self, normal_u, force, multiplier):
        """Primal-dual active-set corrections from {λ⁺ > 0}, refined on Γ_C (rank 0).

        Returns:
            ((p, λ) or None, the number of dense solves).
        """
        if self._compliance is None:
            return None, 0
        sq = self._sqrt_mass
        t = sq * normal_u - self._compliance @ (sq * force)
        guess = self._contact_space_admm(t, normal_u, multiplier) > 0.0
        return self._walk.walk(guess, self._corrections(t), self.max_rounds)

    def _contact_space_admm(self, t, normal_u, multiplier):
        """λ of ADMM on Γ_C from p = min(N u, g), λ = λ⁺ (rank 0; see the module)."""
        _, lam, iterations = contact_space_admm(
            self._compliance,
            t,
            self._sqrt_mass,
            self._gap,
            self.penalty,
            np.minimum(normal_u, self._gap),
            np.maximum(multiplier, 0.0),
            max_iterations=INNER_MAX_ITERATIONS,
        )
        self.inner_iterations += iterations
        return lam

    def _corrections(self, t):
        """The primal-dual active-set step of a set, for the load response t (rank 0)."""
        sq, g = self._sqrt_mass, self._gap
        finite = np.isfinite(g)

        def step(active):
            solution = self._equality_solution(t, active, sq * np.where(active, g, 0.0))
            if solution is None:
                return None, None
            nu, lam = solution[0] / sq, solution[1] / sq
            lam_tol = SIGN_TOL * float(np.max(np.abs(lam)))
            u_tol = SIGN_TOL * max(np.max(np.abs(nu)), np.max(np.abs(g[finite]), initial=0.0))
            leave = active & (lam < -lam_tol)
            join = ~active & (nu > g + u_tol)
            if not leave.any() and not join.any():
                return (np.minimum(nu, g), np.maximum(lam, 0.0)), None
            return None, (active & ~leave) | join

        return step

    def _equality_solution(self, t, active, y_active):
        """Solve (I − rT) ŷ + T λ̂ = t with ŷ_𝒜 given and λ̂ = 0 off 𝒜 (rank 0)."""
        r, T, shifted = self.penalty, self._compliance, self._shifted
        free = ~active
        system = np.empty_like(T)
        system[:, free] = shifted[:, free]
        system[:, active] = r * T[:, active]  # unknown λ̂/r: columns of the same scale
        try:
            x = np.linalg.solve(system, t - shifted[:, active] @ y_active[active])
        except np.linalg.LinAlgError:
            return None
        if not np.all(np.isfinite(x)):
            return None
        y_hat = np.where(active, y_active, x)
        lam_hat = np.where(active, r * x, 0.0)
        return y_hat, lam_hat


def contact_space_admm(
    compliance: npt.NDArray[np.float64],
    load_response: npt.NDArray[np.float64],
    sqrt_mass: npt.NDArray[np.float64],
    gap: npt.NDArray[np.float64],
    r: float,
    p: npt.NDArray[np.float64],
    lam: npt.NDArray[np.float64],
    *,
    alpha: float = INNER_ALPHA,
    stable: int | None = INNER_STABLE,
    change: float = INNER_CHANGE,
    max_iterations: int = INNER_MAX_ITERATIONS,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], int]:
    """ADMM's iteration on Γ_C alone, given T and the load response t (dense).

    Step 1 restricted to the contact nodes is ŷ = t + T M^{½}(r p − λ), N u = M^{-½} ŷ
    (the module docstring); steps 2–3 are the paper's node-wise projection with
    over-relaxation α. With exact step-1 solves the full ADMM makes the same iterates.

    Args:
        compliance: T = Wᵀ (A + rK)⁻¹_CC W at the penalty r (m × m).
        load_response: t (m).
        sqrt_mass: M^{½} (m).
        gap: g (m; +inf where a node can never touch).
        r: The penalty of T.
        p: The starting p (≤ g).
        lam: The starting λ (≥ 0).
        alpha: Over-relaxation.
        stable: Stop once the active set {λ > 0} has not changed for this many
            iterations and the relative change of p is at most ``change`` (None: run
            ``max_iterations``).
        change: See ``stable``.
        max_iterations: The cap.

    Returns:
        p, λ and the number of iterations.
    """
    sq, T = sqrt_mass, compliance
    previous, unchanged, iterations = lam > 0.0, 0, 0
    for iterations in range(1, max_iterations + 1):  # noqa: B007 (returned)
        nu = (load_response + T @ (sq * (r * p - lam))) / sq
        relaxed = alpha * nu + (1.0 - alpha) * p
        p_next = np.minimum(relaxed + lam / r, gap)
        lam = np.maximum(lam + r * (relaxed - gap), 0.0)
        moved = np.linalg.norm(p_next - p) / max(np.linalg.norm(p_next), np.finfo(float).tiny)
        p, active = p_next, lam > 0.0
        unchanged = unchanged + 1 if np.array_equal(active, previous) else 0
        previous = active
        if stable is not None and unchanged >= stable and moved <= change:
            break
    return p, lam, iterations


def _congruence(
    block: npt.NDArray[np.float64], weights: npt.NDArray[np.float64]
) -> npt.NDArray[np.float64]:
    """Wᵀ B W for a W (c × m) with one nonzero per row at most (a dof of C is one node's).

    Column j of W holds node j's normal components: Wᵀ B W sums B's rows and columns
    node by node, O(c²) work where dense products cost O(c²m).
    """
    rows, cols = np.nonzero(weights)
    order = np.argsort(cols, kind="stable")
    rows, cols = rows[order], cols[order]
    values = weights[rows, cols]
    present, starts = np.unique(cols, return_index=True)
    by_node = np.add.reduceat(block[:, rows] * values, starts, axis=1)  # B W, c × |present|
    inner = np.add.reduceat(by_node[rows, :] * values[:, None], starts, axis=0)
    m = weights.shape[1]
    out = np.zeros((m, m))
    out[np.ix_(present, present)] = inner
    return out
