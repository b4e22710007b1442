"""The contact problem's operators: A + rK, condensed or not, and the surface metric.

Between the problem and its users (the penalty estimate and the ADMM): each operator
is built from a :class:`~admm_dolfinx.problem.ContactProblem` with the PETSc tools of
:mod:`admm_dolfinx.linalg`, which know nothing of contact.
"""
