"""Refine a contact problem until a quantity an engineer reads is as accurate as asked.

:func:`solve_adaptive` solves, estimates, marks and refines, level after level:

1. **Solve** the user's problem on the current mesh (``build(mesh, facet_tags)``
   rebuilds their own forms, materials, loads and Dirichlet conditions), started from
   the previous level's solution interpolated
   (:func:`~admm_dolfinx.adapt.refinement.transfer_solution`).
2. **Estimate** the error's distribution over the edges by the hierarchical
   estimator (:mod:`admm_dolfinx.adapt.estimator`), and the quantity's error: a
   local one's (the peak pressure, the contact area) from the last levels
   (:mod:`admm_dolfinx.adapt.quantities`), the contact force's as the relative error
   of the strain energy, η²/(a(u_h, u_h) − η²).
3. **Stop** when the quantity's estimated error is at most ``target``.
4. **Mark** Dörfler's bulk of the edges, and for a local quantity the contact zone
   and a grading around it (:mod:`admm_dolfinx.adapt.marking`), and **refine** them,
   the facet tags carried and Γ_C placed on the body's true surface if one is given
   (:mod:`admm_dolfinx.adapt.refinement`).

Every step is collective and partition-independent (the marking included), so the
levels, and the answer, are the same on any number of processes.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from dolfinx.mesh import Mesh, MeshTags
from mpi4py import MPI

from admm_dolfinx._logging import get_logger, speaking_for
from admm_dolfinx._mpi import collective_call
from admm_dolfinx.adapt.estimator import edge_indicators, relative_energy_error
from admm_dolfinx.adapt.marking import (
    contact_zone_edges,
    count_edges,
    doerfler_edges,
    graded_edges,
)
from admm_dolfinx.adapt.quantities import QUANTITIES, level_estimate, quantity_value
from admm_dolfinx.adapt.recovery import NEIGHBOURS
from admm_dolfinx.adapt.refinement import (
    check_refinable,
    refine_contact_mesh,
    transfer_solution,
)
from admm_dolfinx.adapt.surface import Surface
from admm_dolfinx.admm.result import ADMMResult, WarmStart
from admm_dolfinx.admm.solver import ADMMSolver
from admm_dolfinx.problem.contact_problem import ContactProblem

__all__ = ["AdaptiveLevel", "AdaptiveLimitError", "AdaptiveResult", "solve_adaptive"]

logger = get_logger(__name__)

#: Dörfler's bulk fraction θ by default.
DEFAULT_THETA = 0.5
#: The quantities read off the contact zone: their estimator is localised there
#: (:meth:`~admm_dolfinx.adapt.estimator.EdgeIndicators.localised`), the zone is split
#: at every level and its error is estimated from successive levels
#: (:func:`~admm_dolfinx.adapt.quantities.level_estimate`).
LOCAL_QUANTITIES = ("max_pressure", "contact_area")
#: The quantities of the whole body's stiffness: the contact force, the strain energy's
#: conjugate where the obstacle's motion drives the body. Their error is the relative
#: energy error η²/(a(u_h, u_h) − η²) on each level
#: (:func:`~admm_dolfinx.adapt.estimator.relative_energy_error`), and the marking is
#: Dörfler's alone on the energy-norm estimator: splitting the whole contact zone at
#: every level (what the level differences of a local quantity need) spends the dofs
#: where the energy's error is not.
ENERGY_QUANTITIES = ("contact_force",)


@dataclass(frozen=True)
class AdaptiveLevel:
    """One level of :func:`solve_adaptive`.

    Attributes:
        level: 0 for the given mesh.
        dofs: Displacement dofs (global).
        contact_nodes: Contact nodes m (global).
        active: Contact nodes with λ > 0.
        quantity: The quantity's value on this level.
        estimate: Its estimated relative error (None where not estimable yet).
        resolved: Whether the contact zone was resolved.
        indicator: The hierarchical estimator η = (Σ_e η_e²)^½ (energy norm).
        iterations: ADMM iterations of the solve.
        step1: How the solve's step 1 was solved (``"condensed"``, ``"factorised"``
            or ``"iterative"``, from its plan).
        cpu_seconds: CPU seconds of the level (solve, estimate, marking, refinement),
            summed over the processes.
        wall_seconds: Wall-clock seconds of the level.
        marked: Edges marked for the next level (0 on the last).
    """

    level: int
    dofs: int
    contact_nodes: int
    active: int
    quantity: float
    estimate: float | None
    resolved: bool
    indicator: float
    iterations: int
    step1: str
    cpu_seconds: float
    wall_seconds: float
    marked: int = 0


@dataclass
class AdaptiveResult:
    """What :func:`solve_adaptive` reached.

    Attributes:
        result: The last level's :class:`~admm_dolfinx.ADMMResult`.
        problem: The last level's problem (``result.problem``).
        mesh: The last level's mesh.
        facet_tags: Its facet tags.
        quantity: The name of the controlled quantity.
        value: Its value on the last level.
        estimated_error: Its estimated relative error there (None if not estimable).
        target: The relative error asked for.
        converged: Whether the estimate is at most the target.
        history: Every level, coarse to fine.
    """

    result: ADMMResult
    problem: ContactProblem
    mesh: Mesh
    facet_tags: MeshTags
    quantity: str
    value: float
    estimated_error: float | None
    target: float
    converged: bool
    history: list[AdaptiveLevel] = field(default_factory=list)

    def summary(self) -> str:
        """A table of the levels, and the verdict."""
        lines = [
            f"solve_adaptive: {self.quantity} = {self.value:.6g}, estimated error "
            + (f"{self.estimated_error:.2%}" if self.estimated_error is not None else "unknown")
            + f" (target {self.target:.2%}): "
            + ("reached" if self.converged else "NOT reached"),
            "  level     dofs      m  active  quantity       estimate   iterations  cpu [s]",
        ]
        for h in self.history:
            estimate = "–" if h.estimate is None else f"{h.estimate:.2e}"
            lines.append(
                f"  {h.level:5d} {h.dofs:8d} {h.contact_nodes:6d} {h.active:7d}  "
                f"{h.quantity:<13.6g} {estimate:>9s}   {h.iterations:10d}  {h.cpu_seconds:7.2f}"
            )
        return "\n".join(lines)


class AdaptiveLimitError(RuntimeError):
    """:func:`solve_adaptive` reached ``max_levels`` before the target.

    Attributes:
        adaptive: What it reached (its ``converged`` is False).
    """

    def __init__(self, message: str, adaptive: AdaptiveResult):
        super().__init__(message)
        self.adaptive = adaptive


def _cpu(comm: MPI.Comm) -> float:
    """CPU seconds of this process (summed over the ranks by the caller)."""
    del comm
    return time.process_time()


def _check_arguments(target, quantity, max_levels, theta) -> None:
    if quantity not in QUANTITIES:
        raise ValueError(f"quantity must be one of {tuple(QUANTITIES)}, got {quantity!r}.")
    if isinstance(target, bool) or not isinstance(target, int | float) or not 0.0 < target < 1.0:
        raise ValueError(
            f"target is the relative error asked of the {quantity}, in (0, 1) (0.01 for 1 %); "
            f"got {target!r}."
        )
    if isinstance(max_levels, bool) or not isinstance(max_levels, int) or max_levels < 1:
        raise ValueError(f"max_levels must be an integer ≥ 1, got {max_levels!r}.")
    if not 0.0 < theta <= 1.0:
        raise ValueError(f"theta (Dörfler's bulk fraction) must lie in (0, 1], got {theta!r}.")


def solve_adaptive(
    build: Callable[[Mesh, MeshTags], ContactProblem],
    msh: Mesh,
    facet_tags: MeshTags,
    *,
    target: float,
    quantity: str = "max_pressure",
    max_levels: int = 8,
    theta: float = DEFAULT_THETA,
    surface: Surface | None = None,
    **options: Any,
) -> AdaptiveResult:
    """Refine near the contact until ``quantity``'s estimated error is at most ``target``.

    Args:
        build: ``build(mesh, facet_tags)`` returns the user's
            :class:`~admm_dolfinx.ContactProblem` on a mesh (its forms, material, loads,
            Dirichlet conditions and obstacle rebuilt there); called on every rank.
        msh: The first mesh: triangles or tetrahedra, affine.
        facet_tags: Its facet tags (carried to every refined mesh).
        target: The relative error asked of the quantity, e.g. 0.01.
        quantity: ``"max_pressure"``, ``"contact_force"`` (its magnitude) or
            ``"contact_area"``. The force's error is estimated as the strain energy's
            relative error: the two agree where the obstacle's motion drives the
            body (displacements, no loads); where loads balanced by the contact
            alone fix the force, the estimate is of the energy, and errs on the safe
            side; where supports share the load with the contact it is not a bound.
        max_levels: The most refinements (levels after the first).
        theta: Dörfler's bulk fraction of the estimator marked at each level.
        surface: The body's true surface near Γ_C, as a map from points (k, gdim) to
            the nearest points on it (a curved body's facets are chords of it; without
            the map the refined Γ_C stays the first mesh's polygon).
        **options: Settings of each level's :class:`~admm_dolfinx.ADMMSolver`.

    Returns:
        The last level, its estimate and the history.

    Raises:
        ValueError: For a mesh that cannot be refined (quadrilaterals, hexahedra,
            curved geometry), a ``build`` that does not return a problem on the given
            mesh, or an argument out of range.
        AdaptiveLimitError: If ``max_levels`` refinements do not reach the target (the
            last level is attached as ``err.adaptive``).
    """
    comm = msh.comm
    collective_call(
        comm, lambda: _check_arguments(target, quantity, max_levels, theta), "solve_adaptive"
    )
    check_refinable(msh)
    quiet = _CoarseLevelsQuiet()
    solver_log = logging.getLogger("admm_dolfinx.admm.solver")
    solver_log.addFilter(quiet)
    try:
        with speaking_for(comm):
            return _adapt(
                build, msh, facet_tags, target, quantity, max_levels, theta, surface, options
            )
    finally:
        solver_log.removeFilter(quiet)


class _CoarseLevelsQuiet(logging.Filter):
    """Drop the solver's under-resolution warnings while the levels refine.

    The first levels are coarse on purpose; their warnings would drown the log. Each
    level's verdict stays in ``history`` and the last one's in ``result.warning``.
    """

    def filter(self, record: logging.LogRecord) -> bool:
        return "contact zone is under-resolved" not in record.getMessage()


def _build(
    build: Callable[[Mesh, MeshTags], ContactProblem],
    msh: Mesh,
    facet_tags: MeshTags,
) -> ContactProblem:
    problem = collective_call(msh.comm, lambda: build(msh, facet_tags), "build(mesh, facet_tags)")
    ok = isinstance(problem, ContactProblem) and problem.mesh is msh
    if not msh.comm.allreduce(bool(ok), op=MPI.LAND):  # refused on every rank
        raise ValueError(
            "build(mesh, facet_tags) must return a ContactProblem on the mesh it is given "
            f"(its forms on a function space of that mesh); got {type(problem).__name__}."
        )
    return problem


def _adapt(
    build: Callable[[Mesh, MeshTags], ContactProblem],
    msh: Mesh,
    facet_tags: MeshTags,
    target: float,
    quantity: str,
    max_levels: int,
    theta: float,
    surface: Surface | None,
    options: dict[str, Any],
) -> AdaptiveResult:
    comm = msh.comm
    history: list[AdaptiveLevel] = []
    values: list[float] = []
    resolved: list[bool] = []
    warm: WarmStart | None = None
    previous: tuple[ContactProblem, ADMMResult] | None = None
    coarse: Mesh | None = None  # the mesh the last refinement split
    parents: np.ndarray | None = None  # in coarse, of each owned cell of msh
    for level in range(max_levels + 1):
        cpu0, wall0 = _cpu(comm), time.perf_counter()
        problem = _build(build, msh, facet_tags)
        if previous is not None:
            # the parents hold where build() made the problem on the mesh it was given
            related = problem.mesh is msh and previous[0].mesh is coarse
            warm = transfer_solution(previous[1], problem, parents if related else None)
            previous[0].destroy()  # the coarser level is done with
        with ADMMSolver(problem, **options) as solver:
            result = solver.solve(warm_start=warm)
        values.append(quantity_value(quantity, result))
        zone = result.resolution
        indicators = edge_indicators(problem, result, surface)
        eta2 = indicators.total(comm)
        # a zone of one node (or a few, in 3D) is not resolved whatever its shape; the
        # recovered peak counts only where it is a fit (not the nodal maximum)
        few = 1 if problem.gdim == 2 else 3
        if quantity == "max_pressure":
            few = max(few, NEIGHBOURS[problem.gdim] - 1)
        if quantity in ENERGY_QUANTITIES:
            # the energy's error needs no smooth pressure: a zone of several nodes
            resolved.append(result.num_active > few)
            estimate = relative_energy_error(problem, result, eta2) if resolved[-1] else None
        else:
            resolved.append(bool(zone is not None and zone.resolved and result.num_active > few))
            estimate = level_estimate(values, resolved)
        done = estimate is not None and estimate <= target
        marked = np.zeros(0, dtype=np.int32)
        if not done and level < max_levels and quantity in ENERGY_QUANTITIES:
            marked = doerfler_edges(indicators, theta, comm)
        elif not done and level < max_levels:
            marking = indicators
            marked = contact_zone_edges(problem, result.multiplier)
            if zone is not None and zone.where is not None:
                size = zone.half_width if zone.half_width is not None else zone.patch_radius
                radius = max(size, zone.patch_radius)
                if quantity in LOCAL_QUANTITIES:
                    marking = indicators.localised(zone.where, radius)
                marked = np.union1d(
                    marked, graded_edges(msh, zone.where, radius, 2.0 * zone.patch_radius)
                )
            marked = np.union1d(marked, doerfler_edges(marking, theta, comm)).astype(np.int32)
        bs = problem.V.dofmap.index_map_bs
        record = AdaptiveLevel(
            level=level,
            dofs=problem.V.dofmap.index_map.size_global * bs,
            contact_nodes=problem.num_contact_nodes,
            active=result.num_active,
            quantity=values[-1],
            estimate=estimate,
            resolved=resolved[-1],
            indicator=float(np.sqrt(eta2)),
            iterations=result.iterations,
            step1=result.plan.step1 if result.plan is not None else "",
            cpu_seconds=0.0,
            wall_seconds=0.0,
            marked=count_edges(msh, marked),
        )
        if not done and level < max_levels:
            coarse = msh
            msh, facet_tags, parents = refine_contact_mesh(
                msh, facet_tags, marked, problem.contact_marker, surface
            )
        cpu = float(comm.allreduce(_cpu(comm) - cpu0, op=MPI.SUM))
        wall = time.perf_counter() - wall0
        history.append(_timed(record, cpu, wall))
        logger.info(
            "adaptive level %d: %d dofs, m = %d, %s = %.6g, estimated error %s",
            level,
            record.dofs,
            record.contact_nodes,
            quantity,
            values[-1],
            "–" if estimate is None else f"{estimate:.2e}",
        )
        previous = (problem, result)
        if done:
            break
    assert previous is not None
    problem, result = previous
    adaptive = AdaptiveResult(
        result=result,
        problem=problem,
        mesh=problem.mesh,
        facet_tags=problem.facet_tags,
        quantity=quantity,
        value=values[-1],
        estimated_error=history[-1].estimate,
        target=target,
        converged=bool(history[-1].estimate is not None and history[-1].estimate <= target),
        history=history,
    )
    if not adaptive.converged:
        raise AdaptiveLimitError(
            f"solve_adaptive did not reach the target {target:.2%} for the {quantity} in "
            f"{max_levels} refinements (estimated error "
            + (
                f"{adaptive.estimated_error:.2%}"
                if adaptive.estimated_error is not None
                else "unknown: the contact zone is not resolved yet"
            )
            + f", {history[-1].dofs} dofs): raise max_levels, or start from a finer mesh "
            "near the contact. The last level is attached as `err.adaptive`.",
            adaptive,
        )
    return adaptive


def _timed(record: AdaptiveLevel, cpu: float, wall: float) -> AdaptiveLevel:
    from dataclasses import replace

    return replace(record, cpu_seconds=cpu, wall_seconds=wall)
