"""Hertz validation: errors in p0, a, the force and the pressure profile against mesh size.

    python benchmarks/hertz_validation.py            # cylinder levels 0-5, sphere 0-3
    python benchmarks/hertz_validation.py --quick    # cylinder 0-3, sphere 0-2

Both contact models (``contact_normal="obstacle"``, the default, and ``"body"``, the
paper's) on the plane-strain cylinder (a = R/80) and the sphere (a = R/20, a quarter by
symmetry) on a rigid plane. Prints markdown tables with the observed rates, and writes
out_benchmarks/hertz_validation.csv and hertz_pressure.png (the finest cylinder
profile against Hertz's).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from mpi4py import MPI
from tables import print_and_save

from admm_dolfinx import ADMMSolver
from admm_dolfinx.io.plotting import plot_contact_pressure
from admm_dolfinx.scenes.library import hertz, hertz_sphere
from admm_dolfinx.studies.hertz import hertz_errors, observed_rate


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--half-width", type=float, default=0.1, help="the cylinder's a")
    parser.add_argument("--out", default="out_benchmarks")
    args = parser.parse_args()
    comm = MPI.COMM_WORLD
    bodies = [
        ("cylinder", lambda level: hertz(comm, level=level, half_width=args.half_width), 4, 6),
        ("sphere", lambda level: hertz_sphere(comm, level=level), 3, 4),
    ]
    rows, last = [], None
    for body, build, quick_levels, levels in bodies:
        for model in ("obstacle", "body"):
            errs, body_rows = [], []
            for level in range(quick_levels if args.quick else levels):
                scene = build(level)
                problem = scene.problem(contact_normal=model)
                with ADMMSolver(problem, rtol=1e-9) as solver:
                    result = solver.solve()
                e = hertz_errors(scene, problem, result.multiplier)
                errs.append(e)
                body_rows.append(
                    {
                        "body": body,
                        "contact normal": model,
                        "level": level,
                        "nodes": scene.num_nodes,
                        "m": problem.num_contact_nodes,
                        "h/a": f"{e.h / scene.info['a']:.3g}",
                        "p0 error": f"{e.p0_error:+.2%}",
                        "a in [x_k, x_k+1]": f"[{e.a_inside[0]:.4f}, {e.a_inside[1]:.4f}]",
                        "a error / h": f"{e.a_error / e.h:.2f}",
                        "force error": f"{e.force_error:+.1e}",
                        "L2 error": f"{e.l2_error:.3e}",
                        "iterations": result.iterations,
                    }
                )
                if body == "cylinder" and model == "obstacle":
                    last = (scene, problem, result)
                else:
                    problem.destroy()
            h = np.array([e.h for e in errs])
            l2 = np.array([e.l2_error for e in errs])
            rates = np.log(l2[1:] / l2[:-1]) / np.log(h[1:] / h[:-1])
            for row, rate in zip(body_rows[1:], rates, strict=True):
                row["L2 rate"] = f"{rate:.2f}"
            body_rows[-1]["fitted L2 rate"] = f"{observed_rate(h, l2):.2f}"
            rows += body_rows
    if comm.rank == 0:
        print_and_save(rows, Path(args.out) / "hertz_validation.csv")
    # the finest cylinder profile against Hertz's (analytic values at the same nodes)
    scene, problem, result = last
    xc = problem.contact.coordinates[:, 0]
    a, p0 = scene.info["a"], scene.info["p0"]
    exact = p0 * np.sqrt(np.clip(1 - xc**2 / a**2, 0, None))
    plot_contact_pressure(
        problem,
        [("ADMM", result.multiplier), ("Hertz", exact)],
        Path(args.out) / "hertz_pressure.png",
        title="Hertz: pressure on Γ_C, finest cylinder mesh",
    )


if __name__ == "__main__":
    main()
