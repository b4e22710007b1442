"""The quantities an engineer asks for, and their error estimated from successive levels.

The contact force's error is not estimated here: it is the strain energy's, on each
level (:func:`~admm_dolfinx.adapt.estimator.relative_energy_error`). The peak
pressure's and the contact area's are, as follows.

On every level of :func:`~admm_dolfinx.adapt.adaptive.solve_adaptive` the contact zone's
element size halves (:func:`~admm_dolfinx.adapt.marking.contact_zone_edges`), so a
quantity Q that converges at the order p in that size has, on level k,

    e_k ≈ abs(Q_k − Q_{k−1}) / (2^p − 1)

(Richardson). The order is the one observed on the last three levels, taken within
[1/2, 2]: 2 is the order of the recovered peak (a least-squares quadratic,
:mod:`admm_dolfinx.adapt.recovery`) on a smooth pressure, 1/2 keeps a stalling sequence
from dividing by almost nothing. A level whose contact zone is under-resolved
(:mod:`admm_dolfinx.problem.resolution`) gives no estimate, nor does the next: the
last difference d₁ is always between two resolved levels. The level before them may
be under-resolved: its difference d₀ only sets the order and the guard. Whatever
it is, the estimate is at least d₁/3 (the order taken at most 2), the least that
three resolved levels give too; and an under-resolved level is usually far off
(d₀ ≥ 12 d₁), where the guard d₀/12 is the estimate: more than d₁/3.

The upper end of that range is a trade, measured by
``python benchmarks/work_precision_adaptive.py`` (its levels table): capped at 1, a last
difference much smaller than the one before (the 3D Hertz sphere's last two levels
agree far more closely than the two before) falls back on the earlier difference halved, and the
estimate is several times the true error; capped at 2, it is that difference divided
by 12, close to the true error there. The price: a sequence of true order 1 that
stalls by chance for one level is under-estimated by up to the factor 6 that
separates the two.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

from admm_dolfinx.adapt.recovery import recovered_peak_pressure
from admm_dolfinx.admm.result import ADMMResult

__all__ = ["QUANTITIES", "level_estimate", "quantity_value"]

#: The quantities ``solve_adaptive`` controls, and how each is read off a result: the
#: peak pressure recovered from the nodal values (:mod:`admm_dolfinx.adapt.recovery`),
#: the magnitude of the contact force, the contact area.
QUANTITIES: dict[str, Callable[[ADMMResult], float]] = {
    "max_pressure": lambda result: _recovered_peak(result),
    "contact_force": lambda result: float(np.linalg.norm(result.contact_force)),
    "contact_area": lambda result: float(result.contact_area),
}
#: The orders the estimate takes the observed one within.
ORDER_RANGE = (0.5, 2.0)


def _recovered_peak(result: ADMMResult) -> float:
    if result.problem is None:
        raise ValueError("the result's problem was destroyed: its pressure cannot be recovered")
    return recovered_peak_pressure(result.problem, result.multiplier)


def quantity_value(name: str, result: ADMMResult) -> float:
    """The quantity ``name`` of a result."""
    return QUANTITIES[name](result)


def level_estimate(values: Sequence[float], resolved: Sequence[bool]) -> float | None:
    """The relative error of the last value, from the last levels' values; None if unknown.

    With d₁ = abs(Q_k − Q_{k−1}), d₀ = abs(Q_{k−1} − Q_{k−2}) and the order p observed from
    them (d₀/d₁ = 2^p, taken within :data:`ORDER_RANGE`), the error is

        e_k = max(d₁, d₀ 2^{−p}) / (2^p − 1),

    so that a last difference that is small by chance (the sequence crossing the limit)
    does not pass for convergence: the previous difference, reduced at the order p,
    bounds it from below.

    Args:
        values: The quantity on each level so far.
        resolved: Whether each level's contact zone was resolved.

    Returns:
        e_k / abs(Q_k), or None (fewer than three levels, either of the last two
        under-resolved (the third-last may be: it only sets the order), Q_k = 0, or
        the last three values equal: a quantity that does not move is not converging).
    """
    if len(values) < 3 or not all(resolved[-2:]) or values[-1] == 0.0:
        return None
    last, before = abs(values[-1] - values[-2]), abs(values[-2] - values[-3])
    if last == 0.0 and before == 0.0:  # a quantity that does not move says nothing
        return None
    order = ORDER_RANGE[1]
    if before > 0.0 and last > 0.0:
        order = min(max(math.log2(before / last), ORDER_RANGE[0]), ORDER_RANGE[1])
    rate = 2.0**order
    return max(last, before / rate) / (rate - 1.0) / abs(values[-1])
