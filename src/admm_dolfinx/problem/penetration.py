"""How far the deformed body enters the obstacle itself, not its linearisation.

The contact condition N u ≤ g is the obstacle's surface linearised at each contact
node before the solve: along the normal ν_j of the point closest to x_j, at the
distance g_j. Where the surface turns within a node's displacement (a corner, a small
radius, or a normal a user's ``signed_distance`` gets wrong at an edge), a node can
satisfy its linear condition and still end up inside the obstacle. After a solve,
:func:`obstacle_penetration` asks the obstacle for the signed distance of every
deformed contact node x_j + u_j, and says where the penetration exceeds the
tolerance that the solve met for its linear condition.

This is the check of the default model, ``contact_normal="obstacle"``. The paper's
model (``"body"``) measures the gap along the body's normal instead, which lets a
curved body sink into a plane by construction (``docs/design.md`` §1); it is not
checked here.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from mpi4py import MPI

from admm_dolfinx._mpi import gather_concat
from admm_dolfinx.problem.contact_problem import ContactProblem
from admm_dolfinx.problem.contact_set import evaluate_obstacle
from admm_dolfinx.problem.kkt import contact_length

__all__ = ["ObstaclePenetration", "obstacle_penetration"]

#: A penetration of the obstacle up to this many times the solve's tolerance (of the
#: linear condition, ``kkt_tol`` ℓ) is not reported.
REPORT_FACTOR = 10.0


@dataclass(frozen=True)
class ObstaclePenetration:
    """The deepest penetration of the obstacle by the deformed contact nodes.

    Attributes:
        depth: max_j of −(signed distance of x_j + u_j), 0 if none (absolute).
        allowed: What the solve's tolerance allows: REPORT_FACTOR × kkt_tol × ℓ.
        nodes: How many nodes penetrate deeper than ``allowed`` (all ranks).
        where: The undeformed coordinates of the deepest such node (rank 0: on every
            rank), or None.
        normal: The contact direction that node's linear condition used.
    """

    depth: float
    allowed: float
    nodes: int
    where: tuple[float, ...] | None
    normal: tuple[float, ...] | None

    def message(self) -> str:
        """A warning naming where the obstacle is penetrated, or "" if nowhere."""
        if self.nodes == 0 or self.where is None or self.normal is None:
            return ""
        where = ", ".join(f"{x:.4g}" for x in self.where)
        normal = ", ".join(f"{x:.3g}" for x in self.normal)
        return (
            f"The deformed body enters the obstacle at {self.nodes} contact node(s), by up "
            f"to {self.depth:.3g} at the node at ({where}) ({self.depth / self.allowed:.3g} × "
            f"the tolerance {self.allowed:.3g} of the solve). Its contact condition is the "
            "obstacle linearised before the solve, along the obstacle's normal at the "
            f"node's closest point, here ({normal}); the obstacle's surface turns within "
            "the node's displacement there. Check that the obstacle's signed_distance "
            "gives the right normal at that point (an edge or corner), or apply the load "
            "in steps (problem.update_obstacle / update_load), so that each step moves "
            "the nodes less."
        )


def obstacle_penetration(
    problem: ContactProblem,
    u: npt.NDArray[np.float64],
    multiplier: npt.NDArray[np.float64],
    kkt_tol: float,
) -> ObstaclePenetration | None:
    """The penetration of the obstacle by the deformed contact nodes; collective.

    Args:
        problem: The contact problem.
        u: The displacement's local array (``result.u.x.array``).
        multiplier: λ at the owned contact nodes.
        kkt_tol: The tolerance the solve met.

    Returns:
        The deepest penetration and where it is, or None for the paper's model
        (``contact_normal="body"``).

    Raises:
        ValueError: On every rank, if the obstacle's answer is unusable (as when the
            problem was built).
    """
    c = problem.contact
    if c.contact_normal != "obstacle":
        return None
    bs = problem.V.dofmap.index_map_bs
    displacement = u.reshape(-1, bs)[c.nodes, : problem.gdim]
    deformed = c.coordinates + displacement
    gap, _ = evaluate_obstacle(
        problem.obstacle, deformed, c.body_normals, problem.comm, c.contact_normal
    )
    depth = np.where(np.isfinite(gap), np.maximum(-gap, 0.0), 0.0)
    nu = np.einsum("ij,ij->i", displacement, c.normals)
    allowed = max(
        REPORT_FACTOR * kkt_tol * contact_length(problem, nu, multiplier),
        64 * np.finfo(np.float64).eps * problem.length_scale,  # the distance's round-off
    )
    deep = depth > allowed
    count = int(problem.comm.allreduce(int(np.count_nonzero(deep)), op=MPI.SUM))
    deepest = float(problem.comm.allreduce(float(np.max(depth, initial=0.0)), op=MPI.MAX))
    where = normal = None
    if count:
        j = int(np.argmax(depth)) if depth.size else -1
        mine = depth.size > 0 and depth[j] == deepest
        candidates = gather_concat(
            problem.comm,
            c.coordinates[[j]] if mine else np.zeros((0, problem.gdim)),
            c.normals[[j]] if mine else np.zeros((0, problem.gdim)),
        )
        found = None
        if candidates is not None:
            found = (tuple(candidates[0][0].tolist()), tuple(candidates[1][0].tolist()))
        where, normal = problem.comm.bcast(found, root=0)
    return ObstaclePenetration(deepest, allowed, count, where, normal)
