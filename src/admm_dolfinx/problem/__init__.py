"""The discrete contact problem: obstacles, the contact set, checks, KKT, forces, contact zone.

Stage 1 of the pipeline scene → problem → penalty → solver → result → output: from
the user's UFL forms, Dirichlet conditions, facet tags and an analytic obstacle to
the data of the QP minimise ½uᵀAu − fᵀu subject to N u ≤ g.
"""

from admm_dolfinx.problem.contact_problem import ContactProblem
from admm_dolfinx.problem.obstacles import Ball, Obstacle, Plane

__all__ = ["Ball", "ContactProblem", "Obstacle", "Plane"]
