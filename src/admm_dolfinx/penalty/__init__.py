"""The penalty: r* = 1/sqrt(λ_min λ_max) of the contact pencil, and the surface metric's.

Stage 2 of the pipeline. One entry point, :func:`estimate_penalty`; one file per
thing computed: the whole pencil densely (:mod:`.dense`), or its two ends
iteratively, λ_min (:mod:`.lambda_min`) and λ_max (:mod:`.lambda_max`); and β and r of
the surface metric (:mod:`.surface`).
"""

from admm_dolfinx.penalty.estimate import (
    DEFAULT_PENALTY_TOL,
    PENALTY_METHODS,
    PenaltyEstimate,
    estimate_penalty,
)

__all__ = ["DEFAULT_PENALTY_TOL", "PENALTY_METHODS", "PenaltyEstimate", "estimate_penalty"]
