"""Hertz validation: errors in p0, a and the pressure profile against mesh size.

    python benchmarks/hertz_validation.py            # a = 0.1 (R/80), levels 0-5
    python benchmarks/hertz_validation.py --quick    # levels 0-3

Prints a markdown table with the observed rates, and writes
out_benchmarks/hertz_validation.csv and hertz_pressure.png (the finest profile
against Hertz's).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from mpi4py import MPI
from tables import print_and_save

from admm_dolfinx import ADMMSolver
from admm_dolfinx.plotting import plot_contact_pressure
from admm_dolfinx.scenes import hertz
from admm_dolfinx.validation import hertz_errors, observed_rate


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--half-width", type=float, default=0.1)
    parser.add_argument("--out", default="out_benchmarks")
    args = parser.parse_args()
    comm = MPI.COMM_WORLD
    rows, errs = [], []
    for level in range(4 if args.quick else 6):
        scene = hertz(comm, level=level, half_width=args.half_width)
        problem = scene.problem()
        with ADMMSolver(problem, rtol=1e-9) as solver:
            result = solver.solve()
        e = hertz_errors(scene, problem, result.multiplier)
        errs.append(e)
        rows.append(
            {
                "level": level,
                "nodes": scene.num_nodes,
                "m": problem.num_contact_nodes,
                "h": f"{e.h:.3g}",
                "h/a": f"{e.h / scene.info['a']:.3g}",
                "p0 error": f"{e.p0_error:+.2%}",
                "a in [x_k, x_k+1]": f"[{e.a_inside[0]:.4f}, {e.a_inside[1]:.4f}]",
                "a error / h": f"{e.a_error / e.h:.2f}",
                "L2 error": f"{e.l2_error:.3e}",
                "iterations": result.iterations,
            }
        )
        last = (scene, problem, result)
    h = np.array([e.h for e in errs])
    l2 = np.array([e.l2_error for e in errs])
    rates = np.log(l2[1:] / l2[:-1]) / np.log(h[1:] / h[:-1])
    for row, rate in zip(rows[1:], rates, strict=True):
        row["L2 rate"] = f"{rate:.2f}"
    scene, problem, result = last
    if comm.rank == 0:
        a, p0 = scene.info["a"], scene.info["p0"]
        print(
            f"Hertz: R = {scene.info['radius']}, a = {a:.4g}, p0 = {p0:.5g}, "
            f"E = {scene.info['E']}, ν = {scene.info['nu']}\n"
        )
        print_and_save(rows, Path(args.out) / "hertz_validation.csv")
        print(f"\nfitted L2 rate over levels 0-3: {observed_rate(h[:4], l2[:4]):.2f}")
    # the finest profile against Hertz's (analytic values at the same nodes)
    xc = problem.contact.coordinates[:, 0]
    a, p0 = scene.info["a"], scene.info["p0"]
    exact = p0 * np.sqrt(np.clip(1 - xc**2 / a**2, 0, None))
    plot_contact_pressure(
        problem,
        [("ADMM", result.multiplier), ("Hertz", exact)],
        Path(args.out) / "hertz_pressure.png",
        title=f"Hertz: pressure on Γ_C, level {len(errs) - 1}",
    )


if __name__ == "__main__":
    main()
