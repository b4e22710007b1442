"""The 2D defaults on thin strips with 1000 to 20,000 contact nodes (the trust issue).

    python benchmarks/strips.py           # m = 1000, 2500, 5000, 20000
    python benchmarks/strips.py --quick   # m = 1000 (smoke test)

A 20 × 0.1 strip clamped at its left end and pressed onto a rigid plane
(:func:`admm_dolfinx.scenes.hard_cases.strip`) bends like a beam: its contact pencil has a
condition number of 1e9–1e10, which broke the dense r* (SLEPc did not converge) and
is far beyond what ADMM alone converges in. For each size: the default solve (its
path: dense or sparse polishing), iterations, time per phase, KKT residuals, and the
distance to SNES VI on the same discrete problem. Then, side by side in one run, the
two polishing paths on the same problems (the dense one forced, the sparse one forced;
the strips and the paper's compact Example 1):
the time ratio that ``DENSE_COST_RATIO`` in :mod:`admm_dolfinx.operators.condensed` rests on.
Writes out_benchmarks/strips.csv and strips_paths.csv.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from mpi4py import MPI
from tables import print_and_save

from admm_dolfinx import ADMMSolver
from admm_dolfinx.operators import condensed as condensed_module
from admm_dolfinx.scenes.hard_cases import strip
from admm_dolfinx.scenes.library import example1
from admm_dolfinx.studies.baselines import solve_snes_vi


def relative_difference(a, b, comm) -> float:
    num = comm.allreduce(float(np.sum((a.x.array - b.x.array) ** 2)), op=MPI.SUM)
    den = comm.allreduce(float(np.sum(b.x.array**2)), op=MPI.SUM)
    return float(np.sqrt(num / den))


def solve(problem):
    t0 = time.perf_counter()
    with ADMMSolver(problem) as solver:
        result = solver.solve()
        path = type(solver.polisher).__name__ if solver.polisher else "none"
    return result, time.perf_counter() - t0, path


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="m = 1000 only")
    parser.add_argument("--out", default="out_benchmarks")
    args = parser.parse_args()
    comm = MPI.COMM_WORLD
    sizes = (1000,) if args.quick else (1000, 2500, 5000, 20000)
    rows = []
    for cells in sizes:
        scene = strip(comm, cells=cells)
        problem = scene.problem()
        result, elapsed, path = solve(problem)
        reference = solve_snes_vi(problem)
        t = result.timings
        estimate = result.penalty_estimate.as_dict()
        rows.append(
            {
                "m": problem.num_contact_nodes,
                "dofs": problem.V.dofmap.index_map.size_global * 2,
                "polish": {"ActiveSetPolish": "dense", "SparsePolish": "sparse"}.get(path, path),
                "κ (pencil)": f"{estimate['lambda_max'] / estimate['lambda_min']:.2g}",
                "iterations": result.iterations,
                "status": result.status,
                "active": result.num_active,
                "r* [s]": f"{t['penalty']:.2f}",
                "factorisation [s]": f"{t['factorization']:.2f}",
                "iterations [s]": f"{t['iterations']:.2f}",
                "total [s]": f"{elapsed:.2f}",
                "KKT": f"{result.kkt.max():.1e}",
                "|u - u_VI| / |u_VI|": f"{relative_difference(result.u, reference.u, comm):.1e}",
                "SNES VI [s]": f"{reference.time:.2f}",
            }
        )
        problem.destroy()
    if comm.rank == 0:
        print_and_save(rows, Path(args.out) / "strips.csv")

    # the two polishing paths side by side, on the strips and on a compact body
    paths = []
    builders = [(f"strip, {c} cells", lambda c=c: strip(comm, cells=c)) for c in sizes[:2]]
    builders.append(("Example 1, h = 1/128", lambda: example1(comm, h=1 / 128)))
    for label, build in builders:
        scene = build()
        problem = scene.problem()
        times = {}
        for name, limit in (("dense", 10**9), ("sparse", 0)):
            saved = condensed_module.DENSE_COST_RATIO
            condensed_module.DENSE_COST_RATIO = float(limit)
            try:
                result, elapsed, path = solve(problem)
            finally:
                condensed_module.DENSE_COST_RATIO = saved
            times[name] = (elapsed, result.iterations)
        n = problem.V.dofmap.index_map.size_global * 2
        m = problem.num_contact_nodes
        paths.append(
            {
                "scene": label,
                "m": m,
                "dofs": n,
                "m³ / n^1.5": f"{m**3 / n**1.5:.3g}",
                "dense [s]": f"{times['dense'][0]:.2f} ({times['dense'][1]} it.)",
                "sparse [s]": f"{times['sparse'][0]:.2f} ({times['sparse'][1]} it.)",
                "dense / sparse": f"{times['dense'][0] / times['sparse'][0]:.2f}",
            }
        )
        problem.destroy()
    if comm.rank == 0:
        print_and_save(paths, Path(args.out) / "strips_paths.csv")


if __name__ == "__main__":
    main()
