"""admm_dolfinx: frictionless unilateral contact with a rigid obstacle, solved by ADMM.

The package solves the Signorini problem

    minimise ½ uᵀA u − fᵀu   subject to   N u ≤ g

for a linear elastic body (P1 vector Lagrange, DOLFINx 0.11) pressed against an
analytic rigid obstacle, with the alternating direction method of multipliers of
J. Koko (2019) and its automatic penalty parameter r* = 1/sqrt(λ_min λ_max).

Typical use inside a FEniCS workflow::

    problem = admm_dolfinx.ContactProblem(a, L, bcs, facet_tags, contact_marker,
                                          admm_dolfinx.Plane(point, normal))
    result = admm_dolfinx.ADMMSolver(problem).solve()  # penalty='auto': r*
    result.u, result.pressure
"""

from __future__ import annotations

from admm_dolfinx import _bootstrap  # noqa: F401  (must precede dolfinx/petsc4py)
from admm_dolfinx.adapt import AdaptiveLimitError, AdaptiveResult, solve_adaptive
from admm_dolfinx.admm import ADMMConvergenceError, ADMMResult, ADMMSettings, ADMMSolver
from admm_dolfinx.io.paraview import ContactWriter
from admm_dolfinx.penalty import PenaltyEstimate, estimate_penalty
from admm_dolfinx.problem import Ball, ContactProblem, Obstacle, Plane
from admm_dolfinx.problem.kkt import KKTResiduals
from admm_dolfinx.scenes.material import LinearElastic

try:
    from importlib.metadata import version as _version

    __version__ = _version("admm-dolfinx")
except Exception:  # pragma: no cover - running from a source tree without install
    __version__ = "0.0.0+unknown"

__all__ = [
    "ADMMConvergenceError",
    "ADMMResult",
    "ADMMSettings",
    "ADMMSolver",
    "AdaptiveLimitError",
    "AdaptiveResult",
    "Ball",
    "ContactProblem",
    "ContactWriter",
    "KKTResiduals",
    "LinearElastic",
    "Obstacle",
    "PenaltyEstimate",
    "Plane",
    "__version__",
    "estimate_penalty",
    "solve_adaptive",
]
