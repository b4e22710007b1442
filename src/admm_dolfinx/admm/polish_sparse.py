"""Active-set polishing with sparse factorisations: for contact zones too large to be dense.

:mod:`admm_dolfinx.admm.polish_dense` solves the equality-constrained problem of a guessed
contact set 𝒜 on the dense compliance of Γ_C, which costs O(m³) per guess and O(m²)
memory: right for the paper's meshes, out of reach at tens of thousands of contact
nodes. This module solves the same problem in the whole body instead,

    minimise ½uᵀAu − fᵀu   subject to   (N u)_j = g_j,  j ∈ 𝒜,

by eliminating the constrained normal displacements with the nodal projector of the
active nodes (:func:`~admm_dolfinx.linalg.contact_space.projected_stiffness`):
u = u_g + w, with u_g the prescribed normal displacements and w the solution of
Â w = P(f − A u_g), Â = P A P + c N_𝒜ᵀN_𝒜 (A with the active normal rows and columns
replaced by c times the identity, in rotated coordinates). λ on 𝒜 then follows from
the residual f − A u = NᵀMλ. Â is solved like step 1:

* **factorised** (a factorised step 1): one sparse numeric factorisation of Â per
  guess (its sparsity is A's, so the symbolic analysis is done once);
* **iterative** (the multigrid path, a body too large to factorise): conjugate
  gradients preconditioned by smoothed-aggregation multigrid with A's rigid body
  modes, the hierarchy built on the first Â and kept (only the Galerkin coarse
  operators follow the next guesses), each solve started from the previous guess's
  displacement u with the new guess's active normal components projected out (w = u −
  u_g: a node that leaves 𝒜 keeps the displacement it had).
  While the set moves by more than :data:`COARSE_MOVES` of its nodes a round, or
  sheds the rim of a guess too large (below), its solves stop at
  :data:`COARSE_RTOL`: the signs far from zero, which are the moves then, are
  already right, and each round costs a fraction of an exact solve. From there on,
  and always for the set it returns, the solves stop at :data:`POLISH_RTOL_FACTOR` ×
  ``kkt_tol``: the signs of a state it returns, and its KKT residuals, are those of
  the exact solve.

Distributed like step 1, on any partition.

As the dense polisher, it corrects the guess by primal-dual active-set steps (nodes
with λ < 0 leave 𝒜, nodes that penetrate join it; at most :data:`MAX_SPARSE_ROUNDS`
new ones per attempt, each computed once per solve: :mod:`admm_dolfinx.admm.active_set`),
returns only a state that meets every sign condition, and skips attempts while it
has taken longer than the rest of the iterations.

A guess too large (the second of a floating body's walk: the first few nodes hold it
so stiffly that most of Γ_C penetrates) sheds only the rim of its excess per step,
where the pressure of the forced shape turns to tension; the band inside the rim
follows in the next steps, and the excess shrinks by a fraction per step. After a
coarse round that joins nodes (the guess too small whose step is too large), a
coarse round that only sheds nodes therefore sheds :data:`SHED_FACTOR` times as
many, the rim and the kept nodes of least λ next to it, and stays coarse however few
nodes the rim holds, until a round after such a one has nodes to join (it overshot):
plain steps follow from there, and the exact rounds decide the set as before. A
first guess only slightly too large (a warm start) takes the plain steps.
``python benchmarks/floating_3d.py`` runs the walk with and without the shedding.
"""

from __future__ import annotations

import hashlib
import math
import time
from collections.abc import Mapping
from typing import Any

import numpy as np
import numpy.typing as npt
from mpi4py import MPI
from petsc4py import PETSc

from admm_dolfinx._logging import get_logger
from admm_dolfinx.admm.active_set import ActiveSetWalk
from admm_dolfinx.admm.inexact import TAU_FLOOR
from admm_dolfinx.admm.polish_dense import SIGN_TOL
from admm_dolfinx.linalg.contact_space import NodalMap, ProjectedStiffness
from admm_dolfinx.linalg.galerkin import add_to_hierarchy, sparse_difference
from admm_dolfinx.linalg.petsc import (
    check_solve,
    create_factor_solver,
    factor_options,
    prefixed_options,
)
from admm_dolfinx.linalg.smoothers import solve_spd
from admm_dolfinx.problem.contact_problem import ContactProblem

__all__ = ["COARSE_RTOL", "MAX_SPARSE_ROUNDS", "POLISH_RTOL_FACTOR", "SparsePolish"]

logger = get_logger(__name__)

#: An iterative polish solves Â to this factor times the KKT tolerance (relative
#: residual): its displacement error is then well below what the final KKT check
#: measures.
POLISH_RTOL_FACTOR = 1e-3

#: An iterative polish's sign conditions hold to this factor times its solves'
#: relative residual (SIGN_TOL where that is smaller).
SIGN_FACTOR = 10.0

#: The relative residual of an iterative polish's rounds while the set moves a lot:
#: signs read to SIGN_FACTOR times it (a thousandth of the largest λ), where a round
#: that far from the answer moves nodes whose λ or penetration is much larger. Looser
#: (10⁻³) misread a sign near the end of the Hertz ball's walk and cost a round; the
#: walk's Krylov iterations are printed by ``python benchmarks/floating_3d.py``.
COARSE_RTOL = 1e-4
#: A coarse round that only sheds nodes (a guess too large) sheds this many times as
#: many, those with the least λ next to the rim (:meth:`SparsePolish._shed_more`).
SHED_FACTOR = 2.0
#: The coarse rounds end at the first round that moves at most this share of the
#: guessed set's nodes (or none: a set is returned only after an exact solve), unless
#: it sheds the rim of a guess too large (see the module's docstring).
COARSE_MOVES = 0.02

#: A guess holds the floating motions where the smallest eigenvalue of their normal
#: displacements' Gram matrix on 𝒜 exceeds this fraction of the largest on Γ_C.
HOLD_TOL = 1e-10

#: Primal-dual active-set corrections of one guess. Where the contact zone's edge
#: moves by a node per round (a beam lifting off near a clamp) it needs more rounds
#: than the dense polisher's 10; each costs a factorisation, and the time budget of
#: the polisher bounds the total.
MAX_SPARSE_ROUNDS = 50


class SparsePolish:
    """Exact solutions for guessed active sets, by sparse factorisations of the body.

    The interface of :class:`~admm_dolfinx.admm.polish_dense.ActiveSetPolish`.

    Args:
        problem: The contact problem.
        prefix: Options prefix of the solver of Â (``{prefix}`` + PETSc options).
        petsc_options: Options of that solver: MUMPS Cholesky by default; Krylov
            options (``ksp_type`` other than ``preonly``, as an iterative step 1's)
            make the polish iterative.
        kkt_tol: The KKT tolerance of the solve; an iterative polish solves Â to
            :data:`POLISH_RTOL_FACTOR` times it.

    Attributes:
        attempts: Guesses tried since :meth:`reset`.
        rounds: Solves with Â (factorisations, when factorised) since :meth:`reset`.
        krylov_iterations: Krylov iterations of an iterative polish since :meth:`reset`.
        displacement: The displacement u of the last state :meth:`attempt` returned
            (owned values), or None: the iteration starts its evaluation there.
        setup_time: 0 (nothing is set up per penalty).
        skipped: Attempts skipped for time since :meth:`reset`.
        time: Seconds spent since :meth:`reset`.
    """

    def __init__(
        self,
        problem: ContactProblem,
        prefix: str,
        petsc_options: Mapping[str, Any] | None = None,
        kkt_tol: float = 1e-6,
    ):
        self.problem = problem
        self.comm: MPI.Comm = problem.comm
        self.prefix = prefix
        self._options = dict(petsc_options or {})
        #: Whether Â is solved by a Krylov method (the multigrid path).
        self.iterative = factor_options(self._options).get("ksp_type") != "preonly"
        #: The relative residual an iterative polish solves Â to.
        self.solve_rtol = 0.0
        self.set_kkt_tol(kkt_tol)
        self.displacement: npt.NDArray[np.float64] | None = None
        self.krylov_iterations = 0
        self._start: PETSc.Vec | None = None
        #: Whether the multigrid of Â follows the guesses by projected changes.
        self._updates = True
        #: Primal-dual active-set corrections per guess.
        self.max_rounds = MAX_SPARSE_ROUNDS
        self.penalty = float("nan")
        self.setup_time = 0.0
        self._matrix: PETSc.Mat | None = None
        #: Â of each guess (one pattern: the triple product's symbolic phase done once).
        self._former: ProjectedStiffness | None = None
        self._ksp: PETSc.KSP | None = None
        self._walk: ActiveSetWalk[tuple] = ActiveSetWalk(self._key)
        self.attempts = self.rounds = self.skipped = 0
        self.time = 0.0

    def set_kkt_tol(self, kkt_tol: float) -> None:
        """Solve Â (iteratively) to :data:`POLISH_RTOL_FACTOR` times a new KKT tolerance."""
        self.solve_rtol = max(TAU_FLOOR, POLISH_RTOL_FACTOR * kkt_tol)

    def set_penalty(self, r: float) -> None:
        """Nothing depends on r (the equality-constrained problem does not)."""
        self.penalty = float(r)

    def reset(self) -> None:
        """Start a solve: forget the walk's steps; collective."""
        self._walk.clear()
        self.attempts = self.rounds = self.skipped = self.krylov_iterations = 0
        self.displacement = None
        self.time = 0.0

    def destroy(self) -> None:
        """Free the factorisation; collective."""
        for obj in (self._ksp, self._matrix, self._start, self._former):
            if obj is not None:
                obj.destroy()
        self._ksp = self._matrix = self._start = self._former = None

    # ------------------------------------------------------------------ attempt
    def attempt(
        self,
        normal_u: npt.NDArray[np.float64],
        force: npt.NDArray[np.float64],
        multiplier: npt.NDArray[np.float64],
        budget: float = math.inf,
    ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]] | None:
        """The exact state (p, λ) for the active set {λ⁺ > 0}, or None; collective.

        Args:
            normal_u: N u of a step-1 solve (unused: the solve starts from the load).
            force: Its normal force (unused).
            multiplier: λ⁺ of the same iteration (local): the guess is {λ⁺ > 0}.
            budget: Seconds the caller has spent otherwise: while the polishing time
                so far exceeds it, the attempt is skipped.

        Returns:
            The local parts of p = min(N u, g) and λ ≥ 0, or None.
        """
        del normal_u, force
        t0 = time.perf_counter()
        if self.comm.allreduce(self.time > budget, op=MPI.LOR):
            self.skipped += 1
            return None
        c = self.problem.contact
        gap = c.gap
        finite = np.isfinite(gap)
        active = (multiplier > 0.0) & finite

        # the rounds of an iterative polish start coarse (COARSE_RTOL) while the set
        # moves a lot; a set is returned only from a solve to solve_rtol
        coarse = self.iterative and COARSE_RTOL > self.solve_rtol
        provisional: list[npt.NDArray[np.bool_]] = []  # the sets stepped from coarsely
        # after a coarse round that joins nodes (a guess too small, whose step is too
        # large), a coarse round that only sheds nodes sheds more (_shed_more), until a
        # round after such a one has nodes to join: the set overshot, plain steps follow
        shedding, armed, shed_last = coarse and SHED_FACTOR > 1.0, False, False

        def moves(active, rtol):
            """(N u, λ, u) of 𝒜 solved to rtol, the nodes that leave and join, and their count."""
            nu, lam, u = self._equality_solution(active, rtol)
            self.rounds += 1
            # an iterative solve's λ and N u are as accurate as its residual: signs
            # below that are noise, not moves
            tolerance = max(SIGN_TOL, SIGN_FACTOR * rtol) if self.iterative else SIGN_TOL
            lam_tol = tolerance * self.problem.global_norm(lam, np.inf)
            scale = max(
                self.problem.global_norm(nu, np.inf),
                self.problem.global_norm(np.where(finite, gap, 0.0), np.inf),
            )
            leave = active & (lam < -lam_tol)
            join = ~active & finite & (nu > gap + tolerance * scale)
            changes = self.comm.allreduce(int(leave.sum() + join.sum()), op=MPI.SUM)
            return (nu, lam, u), leave, join, changes

        def step(active):
            nonlocal coarse, shedding, armed, shed_last
            if not self._holds(active):  # Â singular: no equality solution
                return None, None
            if coarse:
                state, leave, join, changes = moves(active, COARSE_RTOL)
                size = self.comm.allreduce(int(active.sum()), op=MPI.SUM)
                joining = self.comm.allreduce(int(join.sum()), op=MPI.SUM)
                if joining and shed_last:
                    shedding = False  # the last shed overshot: plain steps from here
                shed_last = shedding and armed and changes > 0 and not joining
                armed = armed or bool(joining)
                # a guess too large is far from the answer however few nodes its rim
                # holds (a coarse mesh far from the zone): it stays coarse while it sheds
                coarse = shed_last or changes > COARSE_MOVES * size
                if coarse:
                    provisional.append(active)
                if shed_last:
                    leave = leave | self._shed_more(active & ~leave, state[1], changes)
            if not coarse:  # also the exact solve of a set the coarse round kept
                state, leave, join, changes = moves(active, self.solve_rtol)
            if changes == 0:
                nu, lam, u = state
                return (np.minimum(nu, gap), np.where(active, np.maximum(lam, 0.0), 0.0), u), None
            return None, (active & ~leave) | join

        outcome, rounds = self._walk.walk(active, step, self.max_rounds)
        # a coarse step is not the set's exact step: no later walk follows it
        self._walk.forget(provisional)
        self.attempts += int(rounds > 0)
        self.time += time.perf_counter() - t0
        if outcome is None:
            return None
        p, lam, self.displacement = outcome
        return p, lam

    def _shed_more(
        self, kept: npt.NDArray[np.bool_], lam: npt.NDArray[np.float64], shed: int
    ) -> npt.NDArray[np.bool_]:
        """At most (SHED_FACTOR − 1) × ``shed`` nodes of ``kept``, those of least λ; collective.

        A guess too large by a band sheds its rim (λ < 0) and keeps the band inside it,
        which the next rounds shed in turn: the excess shrinks by a fraction per round.
        Where the pressure falls to zero towards the rim (a Hertzian zone), the least λ
        of the kept nodes are next to it: shedding them now takes the next rounds' steps
        at once. Where it does not (a punch's pressure is least at its centre, a second
        zone may carry little), the next round finds the shed nodes penetrating and
        joins them, which ends the shedding: a round lost, the answer the same (a state
        is returned only from an exact round).

        At most half the kept nodes are shed, and none where the rest would not hold a
        floating body (:meth:`_holds`). Ties at the threshold are kept, on every rank
        alike (the threshold is chosen from the gathered λ of the owned nodes).
        """
        none = np.zeros_like(kept)
        values = np.concatenate(self.comm.allgather(lam[kept]))
        extra = min(int((SHED_FACTOR - 1.0) * shed), values.size // 2)
        if extra <= 0:
            return none
        threshold = np.partition(values, extra)[extra]  # the same on every rank
        more = kept & (lam < threshold)
        return more if self._holds(kept & ~more) else none

    def _holds(self, active: npt.NDArray[np.bool_]) -> bool:
        """Whether the constraints of 𝒜 hold every floating motion; collective.

        A floating body's Â is definite only where the normal displacements (N d_i)_j of
        its free rigid motions d_i at the nodes of 𝒜 span them: otherwise (an empty
        guess, the first iterates of a body with clearance everywhere; too few nodes
        for several free motions) the guess has no equality solution and is skipped.
        """
        motion = self.problem.rigid_motions.normal_motion  # (floating, owned nodes)
        if motion.shape[0] == 0:
            return True
        local = np.stack([motion[:, active] @ motion[:, active].T, motion @ motion.T])
        gram, whole = self.comm.allreduce(local, op=MPI.SUM)
        return bool(np.linalg.eigvalsh(gram)[0] > HOLD_TOL * np.linalg.eigvalsh(whole)[-1])

    def _key(self, active: npt.NDArray[np.bool_]) -> bytes:
        """A digest of the global active set, the same on every rank; collective."""
        digest = hashlib.sha1(np.packbits(active).tobytes()).digest()
        return b"".join(self.comm.allgather(digest))

    def _factorisation(self) -> PETSc.KSP:
        """The KSP of the factorisation that the first :meth:`_equality_solution` made.

        Raises:
            RuntimeError: If there is none (destroyed, or the first factorisation failed).
        """
        if self._ksp is None:
            raise RuntimeError(
                "The sparse active-set polish has no factorisation (it was destroyed, or "
                "its first factorisation failed)."
            )
        return self._ksp

    def _update_multigrid(self, ksp: PETSc.KSP, hat: PETSc.Mat) -> None:
        """Make the multigrid that of Â, its hierarchy kept; collective.

        Â of the next guess differs from the last one in the rows and columns of the
        nodes that joined or left 𝒜: the coarse operators take that change, projected
        (:func:`~admm_dolfinx.linalg.galerkin.add_to_hierarchy`), instead of PETSc's
        Galerkin products of the whole Â. Where that is not possible (another
        preconditioner than multigrid, a pattern PETSc would not add) it is set up
        afresh on Â.
        """
        assert self._matrix is not None
        pc = ksp.getPC()
        if self._updates and pc.getType() in (PETSc.PC.Type.GAMG, PETSc.PC.Type.MG):
            delta = sparse_difference(hat, self._matrix)
            hat.copy(self._matrix, structure=PETSc.Mat.Structure.SAME_NONZERO_PATTERN)
            try:
                # the smoothers are set up again with the walk's options, as PETSc would
                with prefixed_options(self.prefix, self._options):
                    if add_to_hierarchy(pc, self._matrix, delta):
                        return
            finally:
                delta.destroy()
            self._updates = False  # the same on every rank
        hat.copy(self._matrix, structure=PETSc.Mat.Structure.SAME_NONZERO_PATTERN)
        pc.setReusePreconditioner(False)
        ksp.setOperators(self._matrix)
        ksp.setUp()

    def _equality_solution(self, active: npt.NDArray[np.bool_], rtol: float):
        """(N u, λ, u) of the problem with (N u)_j = g_j on ``active``; collective.

        ``rtol`` is an iterative solve's relative residual (a factorisation is exact).
        """
        problem, c = self.problem, self.problem.contact
        bs = problem.V.dofmap.index_map_bs
        nodes = c.nodes[active]
        ntilde = c.free_normals[active]
        nodal = NodalMap(nodes, ntilde, bs, problem.gdim)
        if self._former is None:
            self._former = ProjectedStiffness(problem.A)
        hat = self._former.form(nodal)  # the former's: not destroyed here
        if self._matrix is None:
            self._matrix = hat.duplicate(copy=True)
            self._matrix.setOption(PETSc.Mat.Option.SPD, True)
            # duplicate() drops the rigid-body near null space that multigrid needs
            self._matrix.setNearNullSpace(problem.A.getNearNullSpace())
            ksp = self._ksp = create_factor_solver(
                self._matrix,
                self.prefix,
                self._options,
                problem.gdim,
                what="the sparse active-set polish",
            )
            ksp.setInitialGuessNonzero(self.iterative)
        elif self.iterative:
            ksp = self._factorisation()
            self._update_multigrid(ksp, hat)
        else:
            hat.copy(self._matrix, structure=PETSc.Mat.Structure.SAME_NONZERO_PATTERN)
            ksp = self._factorisation()
            ksp.setOperators(self._matrix)
            ksp.setUp()
        # u_g: the prescribed normal displacement ĝ_j = g_j − (n_j − ñ_j)·u_D at active
        # nodes (the Dirichlet part of the normal), along ñ_j / |ñ_j|²
        x_g, rhs, x, work = (problem.create_vector() for _ in range(4))
        scale = 1.0 / np.einsum("ij,ij->i", ntilde, ntilde)
        try:
            x_g.set(0.0)
            fixed_part = problem.prescribed_normal_displacement()[active]
            target = c.gap[active] - fixed_part
            nodal.scatter(target, x_g, scale)
            problem.A.mult(x_g, work)
            problem.load_vector().copy(rhs)
            rhs.axpy(-1.0, work)  # f − A u_g
            # P: remove the active normal components
            nodal.scatter(nodal.gather(rhs), work, scale)
            rhs.axpy(-1.0, work)
            if self.iterative:  # start from the previous guess's u, projected
                if self._start is None:
                    self._start = problem.create_vector()
                    self._start.set(0.0)
                self._start.copy(x)
                nodal.scatter(nodal.gather(x), work, scale)
                x.axpy(-1.0, work)
                ksp.setTolerances(rtol=rtol)
            if self.iterative:  # a multigrid found indefinite is made careful
                with prefixed_options(self.prefix, self._options):
                    ours = "ksp_max_it" not in self._options
                    solve_spd(ksp, rhs, x, "the sparse active-set polish", limit_is_ours=ours)
            else:
                ksp.solve(rhs, x)
            check_solve(ksp, "the sparse active-set polish")
            x.axpy(1.0, x_g)
            if self.iterative:  # the next guess starts from this u, not from w: a node
                # that leaves 𝒜 keeps the displacement that 𝒜 prescribed it
                assert self._start is not None
                x.copy(self._start)
                self.krylov_iterations += ksp.getIterationNumber()
            problem.A.mult(x, work)
            work.aypx(-1.0, problem.load_vector())  # f − A u = NᵀMλ on the free dofs
            lam = problem.multiplier_from_residual(work)
            nu = problem.apply_normal(x)
            u = x.array_r.copy()
        finally:
            for vec in (x_g, rhs, x, work):
                vec.destroy()
        return nu, np.where(active, lam, 0.0), u
