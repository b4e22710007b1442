"""Steps 2–3 of ADMM, one strategy per penalty metric, with one signature.

Given ξ = α N u + (1 − α) p from step 1, each returns p⁺, λ⁺ and the equilibrium
defect d in pressure units (A u − f + NᵀMλ⁺ = NᵀM d at the contact nodes), and adds
its metric's part to step 1's right-hand side:

* :class:`MassMetricStep`, the paper's metric r M: the node-wise projection
  p⁺ = min(ξ + λ/r, g), λ⁺ = max(λ + r(ξ − g), 0);
* :class:`SurfaceMetricStep`, the metric r(M + βL_Γ): a QP on Γ_C
  (:class:`~admm_dolfinx.admm.surface_projection.SurfaceProjection`).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from petsc4py import PETSc

from admm_dolfinx.admm.surface_projection import SurfaceProjection
from admm_dolfinx.operators.surface_metric import SurfaceMetric

__all__ = ["MassMetricStep", "SurfaceMetricStep"]

Arrays = tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64]]


class MassMetricStep:
    """The paper's steps 2–3 in the metric r M (node-wise, no communication)."""

    name = "mass"

    def __init__(self) -> None:
        self.gap = np.zeros(0)

    def reset(self, gap: npt.NDArray[np.float64], rhs: PETSc.Vec, work: PETSc.Vec, r: float):
        """Start a solve with the current gap; nothing to add to step 1's base load."""
        self.gap = gap

    def add_force(self, b: PETSc.Vec, p: npt.NDArray[np.float64], r: float) -> None:
        """Nothing beyond r NᵀM p (added by the solver for every metric)."""

    def __call__(self, xi, lam, p, normal, r: float) -> Arrays:
        """(p⁺, λ⁺, d) of the node-wise projection."""
        with np.errstate(invalid="ignore"):
            p_new = np.minimum(xi + lam / r, self.gap)
            lam_new = np.maximum(lam + r * (xi - self.gap), 0.0)
        return p_new, lam_new, r * (p - normal) + (lam_new - lam)

    def statistics(self) -> dict[str, int] | None:
        """No statistics."""
        return None

    def destroy(self) -> None:
        """Nothing to free."""


class SurfaceMetricStep:
    """Steps 2–3 in the surface metric r(M + βL_Γ): the QP on Γ_C (distributed).

    Args:
        metric: The surface metric's operators.
        beta: β.
        prefix: Options prefix of the QP's factorisations (``ADMMSettings.prefixes``).
    """

    name = "surface"

    def __init__(self, metric: SurfaceMetric, beta: float, prefix: str):
        self.metric = metric
        self.beta = float(beta)
        self.projection = SurfaceProjection(metric, beta, prefix)

    def reset(self, gap, rhs: PETSc.Vec, work: PETSc.Vec, r: float) -> None:
        """Start a solve: the QP's gap, and the Dirichlet lifting of rβ NᵀL_ΓN in ``rhs``."""
        self.projection.reset(gap)
        if self.metric.dirichlet_lift(work):
            rhs.axpy(r * self.beta, work)

    def add_force(self, b: PETSc.Vec, p: npt.NDArray[np.float64], r: float) -> None:
        """Add r β Nᵀ L_Γ p (the rest of Nᵀ R p = r NᵀM p + r β Nᵀ L_Γ p); collective."""
        self.metric.add_surface_force(b, p, r * self.beta)

    def __call__(self, xi, lam, p, normal, r: float) -> Arrays:
        """(p⁺, λ⁺, d) of the QP; collective."""
        return self.projection(xi, lam, p, normal, r)

    def statistics(self) -> dict[str, int] | None:
        """Active-set rounds and factorisations of the QP so far; collective."""
        return self.projection.statistics()

    def destroy(self) -> None:
        """Free the QP (the metric belongs to the solver)."""
        self.projection.destroy()
