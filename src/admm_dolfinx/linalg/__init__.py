"""Linear algebra: PETSc helpers, the MUMPS Schur binding and the step-1 operators."""
