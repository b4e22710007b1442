"""Optimality (KKT) residuals of a candidate solution of the contact QP.

For  minimise ½uᵀAu − fᵀu  s.t.  Nu ≤ g  with multiplier λ (the contact pressure,
weighted by the lumped mass M), the KKT conditions are

    A u − f + NᵀMλ = 0,   Nu ≤ g,   λ ≥ 0,   λ_j (g_j − (Nu)_j) = 0.

Each residual below is made relative, so that it does not change when the problem is
scaled (E = 1 or E = 1e6, millimetres or metres), and each is measured against a
scale that belongs to the quantity an engineer reads:

* **Force balance.** The sum of the equilibrium residual over the free dofs is what
  the contact force F_c, the support reactions R and the applied loads F_ext fail to
  balance: F_c + R + F_ext = −Σ_free (A u − f + NᵀMλ) (the rigid translations are in
  A's kernel). It is measured against ‖F‖ = max(‖F_c‖, ‖F_ext‖), so that a small
  contact force on a body whose internal forces are large is still right to the
  tolerance (the equilibrium residual, relative to those internal forces, is not
  enough for that).
* **Penetration and complementarity** are measured against a length of the contact,
  :func:`contact_length`, not of the whole body (whose displacement may be a large
  prescribed shear).

They are independent of the solver that produced (u, λ): the same function checks the
ADMM and the baselines.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt
from dolfinx.fem import petsc as fem_petsc
from mpi4py import MPI
from petsc4py import PETSc

if TYPE_CHECKING:
    from admm_dolfinx.problem.contact_problem import ContactProblem

__all__ = [
    "BALANCE_ROUNDOFF",
    "KKTResiduals",
    "compute_kkt_residuals",
    "contact_length",
    "force_balance",
    "gap_residuals",
]


@dataclass(frozen=True)
class KKTResiduals:
    """Relative KKT residuals.

    Attributes:
        primal_feasibility: max_j (N u − g)_j⁺ / ℓ (penetration; ℓ the contact's length,
            :func:`contact_length`).
        dual_feasibility: max_j (−λ_j)⁺ / ‖λ‖_∞ (adhesion, impossible here).
        complementarity: max_j λ_j abs(g_j − (N u)_j) / (‖λ‖_∞ ℓ).
        equilibrium: ‖A u − f + NᵀMλ‖₂ / max(‖A u‖₂, ‖f‖₂, ‖NᵀMλ‖₂), free dofs only.
        force_balance: ‖F_c + R + F_ext‖ / max(‖F_c‖, ‖F_ext‖): how far the contact
            force, the support reactions and the applied loads are from balancing
            (:func:`force_balance`).
    """

    primal_feasibility: float
    dual_feasibility: float
    complementarity: float
    equilibrium: float
    force_balance: float

    def max(self) -> float:
        """Largest of the residuals."""
        return max(asdict(self).values())

    def as_dict(self) -> dict[str, float]:
        """The residuals as a plain dict (for JSON and tables)."""
        return asdict(self)


def _ratio(num: float, den: float) -> float:
    return 0.0 if num == 0.0 else num / den if den > 0.0 else np.inf


def contact_length(
    problem: ContactProblem, nu: npt.NDArray[np.float64], lam: npt.NDArray[np.float64]
) -> float:
    """ℓ, the length against which penetration is judged; collective.

    The larger of

    * the normal displacement abs((N u)_j) of the nodes in contact or penetrating (how far
      the contact zone moved towards the obstacle), and
    * λ_j / k_j, the normal displacement node j's own pressure causes against its
      own stiffness k_j (``problem.contact_stiffness``): the scale of a body pressed
      where it starts in contact (g = 0), whose contact nodes do not move. A
      penetration δ below ε ℓ changes the pressure it implies by no more than ε λ.

    Tangential and prescribed displacements elsewhere (a sheared top) do not enter.

    Args:
        problem: The contact problem.
        nu: N u at the owned contact nodes.
        lam: λ at the owned contact nodes.
    """
    gap = problem.contact.gap
    finite = np.isfinite(gap)
    touching = finite & ((lam > 0.0) | (nu > np.where(finite, gap, 0.0)))
    approach = float(np.max(np.abs(nu[touching]), initial=0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        own = np.where(lam > 0.0, lam / problem.contact_stiffness, 0.0)
    pressed = float(np.max(own, initial=0.0))
    return float(problem.comm.allreduce(max(approach, pressed), op=MPI.MAX))


def gap_residuals(
    problem: ContactProblem,
    nu: npt.NDArray[np.float64],
    lam: npt.NDArray[np.float64],
) -> tuple[float, float]:
    """Relative penetration and complementarity of (N u, λ); collective.

    Args:
        problem: The contact problem.
        nu: N u at the owned contact nodes.
        lam: λ at the owned contact nodes.

    Returns:
        (max_j (N u − g)_j⁺ / ℓ,  max_j λ_j abs(g_j − (N u)_j) / (‖λ‖_∞ ℓ)), with ℓ
        the :func:`contact_length`.
    """
    gap = problem.contact.gap
    slack = np.where(np.isfinite(gap), gap - nu, np.inf)
    penetration = problem.global_norm(np.maximum(-slack, 0.0), np.inf)
    with np.errstate(invalid="ignore"):
        product = np.where(lam != 0.0, np.abs(lam) * np.abs(slack), 0.0)
    lam_scale = problem.global_norm(lam, np.inf)
    length = contact_length(problem, nu, lam)
    return (
        _ratio(penetration, length),
        _ratio(problem.global_norm(product, np.inf), lam_scale * length),
    )


def contact_resultant(
    problem: ContactProblem, lam: npt.NDArray[np.float64]
) -> npt.NDArray[np.float64]:
    """F_c = −Σ_j M_jj λ_j d_j, the force of the obstacle on the body (gdim,); collective."""
    c = problem.contact
    local = -((c.mass * lam)[:, None] * c.normals).sum(axis=0)
    return np.asarray(problem.comm.allreduce(local, op=MPI.SUM), dtype=np.float64)


#: The force balance is judged to this many times the unit round-off of the sum of
#: the forces it adds up (ε Σ_free abs(A u) + abs(f) + abs(NᵀMλ)): a contact force 1e-12 of the
#: internal forces is not resolved below that, whatever the solver. Measured on a
#: contact of one node under a prescribed displacement
#: (``tests/problem/test_force_balance.py``), the exact solution's imbalance is half
#: of that sum's ε.
BALANCE_ROUNDOFF = 10.0
#: The balance is relative to max(‖F_c‖, ‖F_ext‖, this × ‖f‖₂), ‖f‖₂ the load with its
#: lifting by the prescribed displacements (the internal forces they cause): a contact
#: force below 1e-8 of those, and no applied load, count as no force (nothing touches),
#: where the equilibrium residual alone is the measure.
BALANCE_FLOOR = 1e-8


def force_balance(
    problem: ContactProblem,
    free_residual_sum: npt.NDArray[np.float64],
    lam: npt.NDArray[np.float64],
    roundoff: float = 0.0,
) -> float:
    """‖F_c + R + F_ext‖ / max(‖F_c‖, ‖F_ext‖) from Σ_free (A u − f + NᵀMλ); collective.

    (With :data:`BALANCE_FLOOR` ‖f‖₂ as the smallest scale.)

    Args:
        problem: The contact problem.
        free_residual_sum: The equilibrium residual summed over the free dofs per
            direction (gdim,), the same on every rank: −(F_c + R + F_ext).
        lam: λ at the owned contact nodes.
        roundoff: An imbalance that round-off alone explains (absolute), taken off.
    """
    scale = max(
        float(np.linalg.norm(contact_resultant(problem, lam))),
        float(np.linalg.norm(problem.applied_load)),
        BALANCE_FLOOR * problem.load_norm,
    )
    return _ratio(max(float(np.linalg.norm(free_residual_sum)) - roundoff, 0.0), scale)


def _free_sum(problem: ContactProblem, vec: PETSc.Vec) -> npt.NDArray[np.float64]:
    """Σ over the owned entries of ``vec`` (Dirichlet rows zero) per direction; collective."""
    bs = problem.V.dofmap.index_map_bs
    local = vec.array_r.reshape(-1, bs)[:, : problem.gdim].sum(axis=0)
    return np.asarray(problem.comm.allreduce(local, op=MPI.SUM), dtype=np.float64)


def compute_kkt_residuals(
    problem: ContactProblem, u: PETSc.Vec, multiplier: npt.NDArray[np.float64]
) -> KKTResiduals:
    """Evaluate the relative KKT residuals of ``(u, λ)``; collective.

    Args:
        problem: The contact problem.
        u: Displacement (V layout, Dirichlet values included).
        multiplier: λ at the owned contact nodes, shape (m_loc,).

    Returns:
        The residuals.
    """
    lam = np.asarray(multiplier, dtype=np.float64)
    lam_scale = problem.global_norm(lam, np.inf)
    feasibility, complementarity = gap_residuals(problem, problem.apply_normal(u), lam)
    adhesion = problem.global_norm(np.maximum(-lam, 0.0), np.inf)

    Au = problem.create_vector()
    force = problem.create_vector()
    try:
        problem.A.mult(u, Au)
        fem_petsc.set_bc(Au, problem.bcs, alpha=0.0)  # Dirichlet rows are not equations
        force.set(0.0)
        problem.add_normal_force(force, lam)
        scale = max(Au.norm(), problem.load_norm, force.norm())
        magnitudes = Au.norm(PETSc.NormType.NORM_1) + force.norm(PETSc.NormType.NORM_1)
        Au.axpy(-1.0, problem.load_vector())
        fem_petsc.set_bc(Au, problem.bcs, alpha=0.0)
        magnitudes += problem.load_norm_1
        Au.axpy(1.0, force)
        equilibrium = _ratio(Au.norm(), scale)
        roundoff = BALANCE_ROUNDOFF * np.finfo(np.float64).eps * magnitudes
        balance = force_balance(problem, _free_sum(problem, Au), lam, roundoff)
    finally:
        Au.destroy()
        force.destroy()

    return KKTResiduals(
        primal_feasibility=feasibility,
        dual_feasibility=_ratio(adhesion, lam_scale),
        complementarity=complementarity,
        equilibrium=equilibrium,
        force_balance=balance,
    )
