"""The penalty: r* = 1/sqrt(λ_min λ_max) of the contact pencil, and the surface metric's.

Stage 2 of the pipeline. One entry point, :func:`estimate_penalty`; one file per
thing computed: the whole pencil densely (:mod:`.dense`), its two ends iteratively
(:mod:`.iterative`, with the operators of :mod:`.contact_operators` and the LOBPCG of
:mod:`.lobpcg`), and β and r of the surface metric (:mod:`.surface`).
"""

from admm_dolfinx.penalty.estimate import (
    DEFAULT_PENALTY_TOL,
    PENALTY_METHODS,
    PenaltyEstimate,
    estimate_penalty,
)

__all__ = ["DEFAULT_PENALTY_TOL", "PENALTY_METHODS", "PenaltyEstimate", "estimate_penalty"]
