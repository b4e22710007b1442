"""Optimality (KKT) residuals of a candidate solution of the contact QP.

For  minimise ½uᵀAu − fᵀu  s.t.  Nu ≤ g  with multiplier λ (the contact pressure,
weighted by the lumped mass M), the KKT conditions are

    A u − f + NᵀMλ = 0,   Nu ≤ g,   λ ≥ 0,   λ_j (g_j − (Nu)_j) = 0.

Each residual below is made relative, so that it does not change when the problem is
scaled (E = 1 or E = 1e6, millimetres or metres).  They are independent of the
solver that produced (u, λ): the same function checks the ADMM and the baselines.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt
from dolfinx.fem import petsc as fem_petsc
from petsc4py import PETSc

if TYPE_CHECKING:
    from admm_dolfinx.problem.contact_problem import ContactProblem

__all__ = ["KKTResiduals", "compute_kkt_residuals", "gap_residuals"]


@dataclass(frozen=True)
class KKTResiduals:
    """Relative KKT residuals.

    Attributes:
        primal_feasibility: max_j (N u − g)_j⁺ / ‖u‖_∞ (penetration).
        dual_feasibility: max_j (−λ_j)⁺ / ‖λ‖_∞ (adhesion, impossible here).
        complementarity: max_j λ_j abs(g_j − (N u)_j) / (‖λ‖_∞ ‖u‖_∞).
        equilibrium: ‖A u − f + NᵀMλ‖₂ / max(‖A u‖₂, ‖f‖₂, ‖NᵀMλ‖₂), free dofs only.
    """

    primal_feasibility: float
    dual_feasibility: float
    complementarity: float
    equilibrium: float

    def max(self) -> float:
        """Largest of the four residuals."""
        return max(asdict(self).values())

    def as_dict(self) -> dict[str, float]:
        """The residuals as a plain dict (for JSON and tables)."""
        return asdict(self)


def _ratio(num: float, den: float) -> float:
    return 0.0 if num == 0.0 else num / den if den > 0.0 else np.inf


def gap_residuals(
    problem: ContactProblem,
    nu: npt.NDArray[np.float64],
    lam: npt.NDArray[np.float64],
    u_scale: float,
) -> tuple[float, float]:
    """Relative penetration and complementarity of (N u, λ); collective.

    Args:
        problem: The contact problem.
        nu: N u at the owned contact nodes.
        lam: λ at the owned contact nodes.
        u_scale: ‖u‖_∞ (global).

    Returns:
        (max_j (N u − g)_j⁺ / ‖u‖_∞,  max_j λ_j abs(g_j − (N u)_j) / (‖λ‖_∞ ‖u‖_∞)).
    """
    gap = problem.contact.gap
    slack = np.where(np.isfinite(gap), gap - nu, np.inf)
    penetration = problem.global_norm(np.maximum(-slack, 0.0), np.inf)
    with np.errstate(invalid="ignore"):
        product = np.where(lam != 0.0, np.abs(lam) * np.abs(slack), 0.0)
    lam_scale = problem.global_norm(lam, np.inf)
    return (
        _ratio(penetration, u_scale),
        _ratio(problem.global_norm(product, np.inf), lam_scale * u_scale),
    )


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
    u_scale = u.norm(PETSc.NormType.NORM_INFINITY)
    lam_scale = problem.global_norm(lam, np.inf)
    feasibility, complementarity = gap_residuals(problem, problem.apply_normal(u), lam, u_scale)
    adhesion = problem.global_norm(np.maximum(-lam, 0.0), np.inf)

    Au = problem.create_vector()
    force = problem.create_vector()
    try:
        problem.A.mult(u, Au)
        fem_petsc.set_bc(Au, problem.bcs, alpha=0.0)  # Dirichlet rows are not equations
        force.set(0.0)
        problem.add_normal_force(force, lam)
        scale = max(Au.norm(), problem.load_norm, force.norm())
        Au.axpy(-1.0, problem.load_vector())
        fem_petsc.set_bc(Au, problem.bcs, alpha=0.0)
        Au.axpy(1.0, force)
        equilibrium = _ratio(Au.norm(), scale)
    finally:
        Au.destroy()
        force.destroy()

    return KKTResiduals(
        primal_feasibility=feasibility,
        dual_feasibility=_ratio(adhesion, lam_scale),
        complementarity=complementarity,
        equilibrium=equilibrium,
    )
