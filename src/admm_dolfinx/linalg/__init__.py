"""Linear algebra that knows nothing of contact.

PETSc helpers, the MUMPS bindings (analysis, Schur blocks, inverse entries), the
coarse penalty of the multigrid path and the m-vectors of the contact space.
"""
