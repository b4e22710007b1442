"""Studies around the solver: penalty sweeps, reference solvers, the paper's tables, Hertz."""
