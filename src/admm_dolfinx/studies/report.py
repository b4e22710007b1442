"""The standard outputs of a solved scene, written together into one folder.

``solution.xdmf`` (displacement and contact pressure, for ParaView),
``deformed_von_mises.png``, ``normal_stress.png``, optionally
``iterations_vs_r.png`` and ``summary.json``. They appear in the folder only once every
one was written, and nothing else in the folder is touched (see
:func:`admm_dolfinx.io.output.output_folder`).
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np
from mpi4py import MPI

from admm_dolfinx._extras import available, install_hint
from admm_dolfinx._logging import warn
from admm_dolfinx.admm.solver import ADMMResult
from admm_dolfinx.io.output import output_folder, write_json, write_xdmf
from admm_dolfinx.problem.contact_problem import ContactProblem
from admm_dolfinx.scenes.library import Scene
from admm_dolfinx.studies.sweep import PenaltySweep

__all__ = ["result_summary", "write_scene_outputs"]


def result_summary(scene: Scene, problem: ContactProblem, result: ADMMResult) -> dict[str, Any]:
    """A JSON-ready summary of a solve."""
    estimate = result.penalty_estimate.as_dict() if result.penalty_estimate else None
    return {
        "scene": scene.name,
        "info": scene.info,
        "nodes": scene.num_nodes,
        "contact_nodes": problem.num_contact_nodes,
        "processes": problem.comm.size,
        "converged": result.converged,
        "iterations": result.iterations,
        "penalty": result.penalty,
        "penalty_estimate": estimate,
        "active_nodes": result.num_active,
        "max_pressure": result.max_pressure,
        "mean_pressure": result.mean_pressure,
        "contact_area": result.contact_area,
        "contact_force": (
            None if result.contact_force is None else [float(x) for x in result.contact_force]
        ),
        "kkt": result.kkt.as_dict(),
        "timings": result.timings.as_dict(),
        "settings": result.settings.as_dict(),
        "plan": result.plan.describe() if result.plan is not None else None,
    }


def _contact_displacement(problem: ContactProblem, result: ADMMResult) -> np.ndarray | None:
    """The mean displacement of the active contact nodes (None if none); collective."""
    c = problem.contact
    bs = problem.V.dofmap.index_map_bs
    values = result.u.x.array.reshape(-1, bs)[c.nodes, : problem.gdim]
    active = result.multiplier > 0.0
    local = np.concatenate([values[active].sum(axis=0), [float(np.count_nonzero(active))]])
    total = problem.comm.allreduce(local, op=MPI.SUM)
    return None if total[-1] == 0 else total[:-1] / total[-1]


def write_scene_outputs(
    folder: str | os.PathLike,
    scene: Scene,
    problem: ContactProblem,
    result: ADMMResult,
    *,
    sweep: PenaltySweep | None = None,
    coordinate: str = "x",
    extra: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Write the XDMF file, the figures and the JSON summary of a solve; collective.

    Args:
        folder: Output folder (created if need be; only these files are written).
        scene: The scene.
        problem: Its contact problem.
        result: The ADMM result.
        sweep: Iterations against r, for ``iterations_vs_r.png`` (optional).
        coordinate: Abscissa of the 2D normal-stress plot: ``"x"`` or ``"angle"``.
        extra: More entries for ``summary.json``.

    Returns:
        The summary that was written.
    """
    comm = problem.comm
    summary = result_summary(scene, problem, result) | dict(extra or {})
    missing = [name for name in ("pyvista", "matplotlib") if not available(name)]
    if missing:  # what can be written is: the solution and the summary
        warn(
            f"No figures: {' and '.join(missing)} not installed ({install_hint(missing[0])}); "
            "writing solution.xdmf and summary.json only."
        )
        with output_folder(comm, folder) as tmp:
            write_xdmf(tmp / "solution.xdmf", [result.u, result.pressure])
            write_json(comm, tmp / "summary.json", summary)
        return summary

    from admm_dolfinx.io.plotting import (
        obstacle_surface,
        plot_contact_pressure,
        plot_deformed_von_mises,
        plot_iterations_vs_penalty,
    )

    bounds = problem.bounds
    obstacle = obstacle_surface(scene.obstacle, bounds) if comm.rank == 0 else None
    with output_folder(comm, folder) as tmp:
        write_xdmf(tmp / "solution.xdmf", [result.u, result.pressure])
        scale = plot_deformed_von_mises(
            result.u,
            scene.material,
            tmp / "deformed_von_mises.png",
            title=f"{scene.name}: deformed configuration",
            obstacle_mesh=obstacle,
            obstacle_shift=_contact_displacement(problem, result),
        )
        summary["figure_displacement_scale"] = scale
        plot_contact_pressure(
            problem,
            [(f"r = {result.penalty:.4g}", result.multiplier)],
            tmp / "normal_stress.png",
            title=f"{scene.name}: normal stress on Γ_C",
            coordinate=coordinate,
        )
        if sweep is not None:
            marks = [
                (
                    f"r̄ = {sweep.r_best:.4g}: {sweep.iterations_best} it.",
                    sweep.r_best,
                    sweep.iterations_best,
                ),
            ]
            # the sweep penalises in the paper's metric r M; a surface-metric result's
            # r (of r(M + βL_Γ)) is not a point of this curve
            if result.plan is None or result.plan.metric != "surface":
                marks.append(
                    (
                        f"r = {result.penalty:.4g}: {result.iterations} it.",
                        result.penalty,
                        result.iterations,
                    )
                )
            plot_iterations_vs_penalty(
                [(f"{scene.num_nodes} nodes", sweep.r, sweep.iterations)],
                tmp / "iterations_vs_r.png",
                title=f"{scene.name}: iterations against r",
                marks=marks,
                comm=comm,
            )
            summary["sweep"] = {
                "r_best": sweep.r_best,
                "iterations_best": sweep.iterations_best,
                "samples": int(sweep.r.size),
                "time": sweep.time,
            }
        write_json(comm, tmp / "summary.json", summary)
    return summary
