"""Studies around the solver: sweeps, reference solvers, the paper's tables, a scene's report."""
