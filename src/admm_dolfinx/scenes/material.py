"""Isotropic linear elasticity in UFL (small strains, Hooke's law)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import ufl

__all__ = ["LinearElastic"]


@dataclass(frozen=True)
class LinearElastic:
    """Isotropic Hooke material σ(u) = 2μ ε(u) + λ tr ε(u) I.

    In 2D the model is plane strain (the body is a slice of a long prism), as in the
    paper's examples.

    Args:
        E: Young's modulus, > 0.
        nu: Poisson ratio, in (-1, 0.5). ν → 0.5 (incompressible) locks P1 elements and
            makes A singular at ν = 0.5.

    Raises:
        ValueError: For E ≤ 0 or ν outside (-1, 0.5).
    """

    E: float
    nu: float

    def __post_init__(self):
        if not (math.isfinite(self.E) and self.E > 0.0):
            raise ValueError(f"Young's modulus E must be positive and finite, got {self.E}.")
        if not (math.isfinite(self.nu) and -1.0 < self.nu < 0.5):
            raise ValueError(
                f"Poisson ratio must satisfy -1 < ν < 0.5, got ν = {self.nu}. ν = 0.5 is "
                "incompressible and the displacement formulation is singular there; use "
                "ν ≤ 0.499 (P1 elements lock as ν → 0.5)."
            )

    @property
    def mu(self) -> float:
        """Shear modulus μ = E / (2(1 + ν))."""
        return self.E / (2.0 * (1.0 + self.nu))

    @property
    def lmbda(self) -> float:
        """First Lamé parameter λ = Eν / ((1 + ν)(1 − 2ν)) (plane strain in 2D)."""
        return self.E * self.nu / ((1.0 + self.nu) * (1.0 - 2.0 * self.nu))

    @staticmethod
    def strain(u) -> ufl.core.expr.Expr:
        """Small strain ε(u) = sym ∇u."""
        return ufl.sym(ufl.grad(u))

    def stress(self, u) -> ufl.core.expr.Expr:
        """Cauchy stress σ(u)."""
        eps = self.strain(u)
        return 2.0 * self.mu * eps + self.lmbda * ufl.tr(eps) * ufl.Identity(len(u))

    def bilinear_form(self, u, v) -> ufl.Form:
        """The virtual work a(u, v) = ∫ σ(u) : ε(v) dx."""
        return ufl.inner(self.stress(u), self.strain(v)) * ufl.dx

    def von_mises(self, u) -> ufl.core.expr.Expr:
        """Von Mises stress of σ(u); in 2D (plane strain) with σ_zz = ν(σ_xx + σ_yy)."""
        s = self.stress(u)
        d = len(u)
        if d == 2:
            szz = self.nu * (s[0, 0] + s[1, 1])
            dev = (s[0, 0] - s[1, 1]) ** 2 + (s[1, 1] - szz) ** 2 + (szz - s[0, 0]) ** 2
            return ufl.sqrt(0.5 * dev + 3.0 * s[0, 1] ** 2)
        sdev = s - ufl.tr(s) / 3.0 * ufl.Identity(3)
        return ufl.sqrt(1.5 * ufl.inner(sdev, sdev))
