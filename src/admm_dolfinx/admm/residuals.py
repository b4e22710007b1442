"""The residuals of one ADMM iteration, and the stopping test on them.

Every residual is relative, so E = 1 and E = 1e6 stop at the same iteration:

* ``fpr``: the fixed-point residual ‖T(z) − z‖_W / ‖T(z)‖_W of the state z = (p, λ),
  W weighing p by M and λ by M/r² (both parts displacements);
* ``feasibility``, ``complementarity``: penetration and λ·(g − N u) of (u, λ⁺)
  (:func:`~admm_dolfinx.problem.kkt.gap_residuals`);
* ``equilibrium``: A u − f + NᵀMλ⁺ on the free dofs, from the identity
  A u − f + NᵀMλ⁺ = NᵀM d at the contact nodes (d: step 2's defect), so it costs no
  matrix product;
* ``force_balance``: the resultant of that residual against the contact force and the
  load (:func:`~admm_dolfinx.problem.kkt.force_balance`);
* ``du``, ``dp``: the relative changes of u and p (the paper's test).

The loop's residuals rest on identities that assume exact step-1 solves; the solver
confirms a met test with residuals recomputed from (u, λ)
(:func:`~admm_dolfinx.problem.kkt.compute_kkt_residuals`).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import numpy.typing as npt
from petsc4py import PETSc

from admm_dolfinx.admm.anderson import weighted_norm
from admm_dolfinx.problem.contact_problem import ContactProblem
from admm_dolfinx.problem.kkt import _ratio, force_balance, gap_residuals

__all__ = ["HISTORY_KEYS", "IterationResiduals", "ResidualMeter"]

#: The residuals kept per iteration in ``ADMMResult.history`` (and the active count).
HISTORY_KEYS = (
    "du",
    "dp",
    "fpr",
    "feasibility",
    "complementarity",
    "equilibrium",
    "force_balance",
    "active",
)
#: The residuals the ``"kkt"`` stopping test holds to ``rtol``.
KKT_TEST = ("fpr", "feasibility", "complementarity", "equilibrium", "force_balance")


@dataclass(frozen=True)
class IterationResiduals:
    """The residuals of one iteration (the module docstring defines each).

    Attributes:
        res: ‖T(z) − z‖_W, absolute: the safeguard of an extrapolated state compares it.
        fpr: ‖T(z) − z‖_W / ‖T(z)‖_W.
        du: Relative change of u.
        dp: Relative change of p.
        feasibility: Relative penetration of (u, λ⁺).
        complementarity: Relative λ⁺·(g − N u).
        equilibrium: Relative equilibrium residual, from step 2's defect.
        force_balance: Relative resultant of the equilibrium residual.
        active: Global number of contact nodes with λ⁺ > 0.
    """

    res: float
    fpr: float
    du: float
    dp: float
    feasibility: float
    complementarity: float
    equilibrium: float
    force_balance: float
    active: int

    def meets(self, stopping: str, rtol: float) -> bool:
        """Whether the stopping test ``"kkt"`` or ``"change"`` is met at ``rtol``."""
        if stopping == "change":
            return self.du <= rtol and self.dp <= rtol
        return max(getattr(self, key) for key in KKT_TEST) <= rtol

    def as_dict(self) -> dict[str, float]:
        """The residuals by name."""
        return asdict(self)


class ResidualMeter:
    """Measures each iteration's residuals against the previous one; collective.

    It keeps what the changes need (u and p of the previous iteration) and what the
    weights need (the contact mass, r), so that an iteration hands over only its own
    state.

    Args:
        problem: The contact problem.
        r: The penalty.
        u_start: The displacement the iteration starts from (copied).
        p_start: The p of the starting state, at the owned contact nodes.
    """

    def __init__(
        self,
        problem: ContactProblem,
        r: float,
        u_start: PETSc.Vec,
        p_start: npt.NDArray[np.float64],
    ):
        c = problem.contact
        self.problem = problem
        #: |NᵀM e_j| on the free dofs: turns nodal values into the equilibrium residual.
        self.force = np.linalg.norm(c.free_normals, axis=1) * c.mass
        #: The W-norm's weights of z = (p, λ): p by M, λ by M/r².
        self.weights = np.concatenate([c.mass, c.mass / r**2])
        self._u_previous = u_start.copy()
        self._p_previous = np.array(p_start, dtype=np.float64, copy=True)

    def measure(
        self,
        u: PETSc.Vec,
        z: npt.NDArray[np.float64],
        Tz: npt.NDArray[np.float64],
        nu: npt.NDArray[np.float64],
        defect: npt.NDArray[np.float64],
    ) -> IterationResiduals:
        """The residuals of the iteration z ↦ T(z) = (p⁺, λ⁺) with displacement u.

        Args:
            u: The step-1 displacement.
            z: The state the iteration started from, (p, λ).
            Tz: The state it produced, (p⁺, λ⁺).
            nu: N u at the owned contact nodes.
            defect: Step 2's equilibrium defect d (A u − f + NᵀMλ⁺ = NᵀM d).

        Returns:
            The residuals; u and p⁺ become the previous iteration's for the next call.
        """
        problem, comm = self.problem, self.problem.comm
        m = nu.size
        p, lam = Tz[:m], Tz[m:]
        res = weighted_norm(Tz - z, self.weights, comm)
        fpr = _ratio(res, weighted_norm(Tz, self.weights, comm))
        self._u_previous.axpy(-1.0, u)
        du = _ratio(self._u_previous.norm(), u.norm())
        u.copy(self._u_previous)
        dp = _ratio(problem.global_norm(p - self._p_previous), problem.global_norm(p))
        self._p_previous = p.copy()
        feasibility, complementarity = gap_residuals(problem, nu, lam)
        equilibrium = _ratio(
            problem.global_norm(self.force * defect),
            max(problem.load_norm, problem.global_norm(self.force * lam)),
        )
        # Σ_free (A u − f + NᵀMλ⁺) = Σ_j M_jj d_j ñ_j: what the forces fail to balance
        c = problem.contact
        unbalanced = comm.allreduce(((c.mass * defect)[:, None] * c.free_normals).sum(axis=0))
        balance = force_balance(problem, np.asarray(unbalanced, dtype=np.float64), lam)
        return IterationResiduals(
            res=res,
            fpr=fpr,
            du=du,
            dp=dp,
            feasibility=feasibility,
            complementarity=complementarity,
            equilibrium=equilibrium,
            force_balance=balance,
            active=int(comm.allreduce(int(np.count_nonzero(lam > 0.0)))),
        )

    def destroy(self) -> None:
        """Free the previous displacement."""
        self._u_previous.destroy()
