"""Errors of a computed contact pressure against Hertz's analytic solution.

For the plane-strain cylinder on a rigid plane (:func:`admm_dolfinx.scenes.hertz`),
p(x) = p0 sqrt(1 − x²/a²) on |x| ≤ a. The discrete pressure is the nodal λ on Γ_C,
interpolated linearly in x.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from admm_dolfinx._mpi import RankLayout

__all__ = ["HertzErrors", "hertz_errors", "observed_rate"]


@dataclass(frozen=True)
class HertzErrors:
    """Errors of one solve against Hertz.

    Attributes:
        h: Element size in the contact zone.
        p0_error: Relative error of the peak pressure, (max λ − p0)/p0.
        a_inside: (x_k, x_k+1): the last node in contact and the first one out; the
            discrete half-width lies between them.
        a_error: Distance from the analytic a to the interval [x_k, x_k+1] (0 when the
            discrete contact zone brackets a).
        l2_error: ‖p_h − p‖_L2 / ‖p‖_L2 over 0 ≤ x ≤ 2a.
    """

    h: float
    p0_error: float
    a_inside: tuple[float, float]
    a_error: float
    l2_error: float


def hertz_errors(scene, problem, multiplier) -> HertzErrors:
    """Compare λ with Hertz's pressure; collective (gathers Γ_C to every rank).

    Args:
        scene: A :func:`~admm_dolfinx.scenes.hertz` scene (``info`` has ``a``, ``p0``).
        problem: Its contact problem.
        multiplier: λ at the owned contact nodes.

    Returns:
        The errors.
    """
    layout = RankLayout(problem.comm, problem.contact.dofs.size)
    x = layout.allgather(problem.contact.coordinates[:, 0])
    lam = layout.allgather(multiplier)
    a, p0 = scene.info["a"], scene.info["p0"]
    order = np.argsort(x)
    xs, ls = x[order], lam[order]
    k = int(np.flatnonzero(ls > 0).max())
    inside = (float(xs[k]), float(xs[min(k + 1, xs.size - 1)]))
    a_error = max(inside[0] - a, a - inside[1], 0.0)
    s = np.linspace(0.0, 2.0 * a, 20001)
    ph = np.interp(s, xs, ls)
    pe = p0 * np.sqrt(np.clip(1.0 - s**2 / a**2, 0.0, None))
    l2 = float(np.sqrt(np.trapezoid((ph - pe) ** 2, s) / np.trapezoid(pe**2, s)))
    return HertzErrors(
        h=scene.h,
        p0_error=float(ls.max() / p0 - 1.0),
        a_inside=inside,
        a_error=a_error,
        l2_error=l2,
    )


def observed_rate(h, errors) -> float:
    """Least-squares slope of log(error) against log(h)."""
    return float(np.polyfit(np.log(h), np.log(errors), 1)[0])
