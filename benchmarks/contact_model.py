"""What the contact model changes: along the obstacle's normal (default) or the body's.

    python benchmarks/contact_model.py
    python benchmarks/contact_model.py --quick   # the 2D scenes only

For curved bodies on a rigid plane, side by side in one run: a half-disc and a
half-ball pressed far (7.5 gaps: the contact zone's half-width exceeds R/3), the Hertz
cylinder and sphere (small contact zones), and the paper's Example 2 and 3. For each,
with ``contact_normal="obstacle"`` and ``"body"`` (the paper's model): the distance of
the lowest node below the plane (relative to the initial gap where there is one), the
contact force, and the distance of the two solutions; against SNES VI with bounds
where every contact direction is axis-aligned. Writes out_benchmarks/contact_model.csv.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from mpi4py import MPI
from tables import print_and_save

from admm_dolfinx import ADMMSolver
from admm_dolfinx.problem.forces import contact_force
from admm_dolfinx.scenes.library import example2, example3, hertz, hertz_sphere, pressed_ball
from admm_dolfinx.studies.baselines import solve_snes_vi


def norm(x, comm):
    return float(np.sqrt(comm.allreduce(float(x @ x), op=MPI.SUM)))


def lowest(problem, result, comm) -> float:
    """The lowest point of Γ_C after deformation, relative to the plane z = plane point."""
    c = problem.contact
    bs = problem.V.dofmap.index_map_bs
    z = c.coordinates[:, -1] + result.u.x.array.reshape(-1, bs)[c.nodes, problem.gdim - 1]
    plane = problem.obstacle.point[-1] if hasattr(problem.obstacle, "point") else np.nan
    return float(comm.allreduce(float((z - plane).min(initial=np.inf)), op=MPI.MIN))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="the 2D scenes only")
    parser.add_argument("--out", default="out_benchmarks")
    args = parser.parse_args()
    comm = MPI.COMM_WORLD
    scenes = [
        ("half-disc pressed 7.5 gaps", lambda: pressed_ball(comm, gdim=2, push=0.15)),
        ("half-ball pressed 7.5 gaps", lambda: pressed_ball(comm, gdim=3, push=0.15)),
        ("Hertz cylinder (a = R/80)", lambda: hertz(comm, level=2, half_width=0.1)),
        ("Hertz sphere (a = R/20)", lambda: hertz_sphere(comm, level=1)),
        ("Example 2 (Hertz, level 0)", lambda: example2(comm, level=0)),
        ("Example 3 (block on ball, level 0)", lambda: example3(comm, level=0)),
    ]
    if args.quick:
        scenes = [scenes[0], scenes[2], scenes[4]]
    rows = []
    for label, build in scenes:
        scene = build()
        results = {}
        for model in ("obstacle", "body"):
            problem = scene.problem(contact_normal=model)
            with ADMMSolver(problem, rtol=1e-10) as solver:
                result = solver.solve()
            force = contact_force(problem, result.multiplier)
            try:
                vi = solve_snes_vi(problem)
                to_vi = norm(result.u.x.array - vi.u.x.array, comm) / norm(vi.u.x.array, comm)
            except ValueError:  # not axis-aligned: SNES VI's bounds do not apply
                to_vi = np.nan
            results[model] = (problem, result, force, to_vi)
        (p_o, r_o, f_o, vi_o), (p_b, r_b, f_b, _) = results["obstacle"], results["body"]
        gap = scene.info.get("gap")
        below = [lowest(p, r, comm) for p, r in ((p_o, r_o), (p_b, r_b))]
        scale = gap if gap else 1.0

        def shown(depth: float, scale: float = scale, gap=gap) -> str:  # planes only
            if np.isnan(depth):
                return "–"
            return f"{depth / scale:+.1e}" + (" gap" if gap else "")

        rows.append(
            {
                "scene": label,
                "m": p_o.num_contact_nodes,
                "lowest node (obstacle)": shown(below[0]),
                "lowest node (body)": shown(below[1]),
                "|F| body / obstacle": f"{np.linalg.norm(f_b) / np.linalg.norm(f_o):.4f}",
                "|u_body − u_obstacle| / |u|": (
                    f"{norm(r_b.u.x.array - r_o.u.x.array, comm) / norm(r_o.u.x.array, comm):.1e}"
                ),
                "obstacle vs SNES VI": "–" if np.isnan(vi_o) else f"{vi_o:.1e}",
                "iterations (obstacle / body)": f"{r_o.iterations} / {r_b.iterations}",
            }
        )
    if comm.rank == 0:
        print_and_save(rows, Path(args.out) / "contact_model.csv")


if __name__ == "__main__":
    main()
