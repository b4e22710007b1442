"""Adaptive refinement to a target error of a quantity an engineer reads.

Stage 5 of the pipeline, after the result: estimate its error, mark, refine, solve
again (:func:`~admm_dolfinx.adapt.adaptive.solve_adaptive`).
"""

from admm_dolfinx.adapt.adaptive import (
    AdaptiveLevel,
    AdaptiveLimitError,
    AdaptiveResult,
    solve_adaptive,
)

__all__ = ["AdaptiveLevel", "AdaptiveLimitError", "AdaptiveResult", "solve_adaptive"]
