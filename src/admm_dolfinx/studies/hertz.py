"""Errors of a computed contact pressure against Hertz's analytic solutions.

* The plane-strain cylinder on a rigid plane (:func:`admm_dolfinx.scenes.hertz`):
  p(x) = p0 sqrt(1 − x²/a²) on |x| ≤ a; the discrete pressure (nodal λ on Γ_C) is
  interpolated linearly in x.
* The sphere on a rigid plane (:func:`admm_dolfinx.scenes.library.hertz_sphere`):
  p(r) = p0 sqrt(1 − r²/a²) on r ≤ a, r the distance from the axis; the L2 error is
  the lumped-mass weighted nodal one.

Both model a symmetric part of the body (a quarter), which carries the share
``symmetry`` of the total force.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from admm_dolfinx._mpi import RankLayout
from admm_dolfinx.problem.forces import contact_force

__all__ = ["HertzErrors", "hertz_errors", "observed_rate"]


@dataclass(frozen=True)
class HertzErrors:
    """Errors of one solve against Hertz.

    Attributes:
        h: Element size in the contact zone.
        p0_error: Relative error of the peak pressure, (max λ − p0)/p0.
        a_inside: (x_k, x_k+1): the last node in contact and the first one out, by
            distance from the axis; the discrete half-width lies between them.
        a_error: Distance from the analytic a to the interval [x_k, x_k+1] (0 when the
            discrete contact zone brackets a).
        l2_error: ‖p_h − p‖_L2 / ‖p‖_L2 over the nodes within 2a of the axis.
        force_error: Relative error of the total contact force against the load.
    """

    h: float
    p0_error: float
    a_inside: tuple[float, float]
    a_error: float
    l2_error: float
    force_error: float


def hertz_errors(scene, problem, multiplier) -> HertzErrors:
    """Compare λ with Hertz's pressure; collective (gathers Γ_C to every rank).

    Args:
        scene: A :func:`~admm_dolfinx.scenes.hertz` or
            :func:`~admm_dolfinx.scenes.library.hertz_sphere` scene (``info`` has ``a``,
            ``p0`` and ``load``, the force on the whole body).
        problem: Its contact problem.
        multiplier: λ at the owned contact nodes.

    Returns:
        The errors.
    """
    c = problem.contact
    layout = RankLayout(problem.comm, c.dofs.size)
    radial = np.linalg.norm(c.coordinates[:, : problem.gdim - 1], axis=1)
    x = layout.allgather(radial)
    lam = layout.allgather(multiplier)
    mass = layout.allgather(c.mass)
    a, p0 = scene.info["a"], scene.info["p0"]
    order = np.argsort(x)
    xs, ls = x[order], lam[order]
    k = int(np.max(np.flatnonzero(ls > 0)))
    inside = (float(xs[k]), float(xs[min(k + 1, xs.size - 1)]))
    a_error = max(inside[0] - a, a - inside[1], 0.0)
    if problem.gdim == 2:
        s = np.linspace(0.0, 2.0 * a, 20001)
        ph = np.interp(s, xs, ls)
        pe = p0 * np.sqrt(np.clip(1.0 - s**2 / a**2, 0.0, None))
        l2 = float(np.sqrt(np.trapezoid((ph - pe) ** 2, s) / np.trapezoid(pe**2, s)))
        share = 0.5  # the quarter cylinder: half of the (plane) body
    else:
        near = x < 2.0 * a
        pe = p0 * np.sqrt(np.clip(1.0 - x**2 / a**2, 0.0, None))
        w = mass * near
        l2 = float(np.sqrt(np.sum(w * (lam - pe) ** 2) / np.sum(w * pe**2)))
        share = 0.25  # the quarter sphere
    force = float(np.linalg.norm(contact_force(problem, multiplier)))
    return HertzErrors(
        h=scene.h,
        p0_error=float(np.max(ls) / p0 - 1.0),
        a_inside=inside,
        a_error=a_error,
        l2_error=l2,
        force_error=force / (share * scene.info["load"]) - 1.0,
    )


def observed_rate(h, errors) -> float:
    """Least-squares slope of log(error) against log(h)."""
    return float(np.polyfit(np.log(h), np.log(errors), 1)[0])
