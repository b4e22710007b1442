"""The ADMM iteration: the solver, Anderson acceleration, polishing, the surface metric.

Stage 3 of the pipeline: from the problem and its penalty to a result.
"""

from admm_dolfinx.admm.result import ADMMConvergenceError, ADMMResult
from admm_dolfinx.admm.settings import ADMMSettings
from admm_dolfinx.admm.solver import ADMMSolver

__all__ = ["ADMMConvergenceError", "ADMMResult", "ADMMSettings", "ADMMSolver"]
