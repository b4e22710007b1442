"""Where a factorised step 1 stops paying in 3D: the two paths side by side on held bodies.

The plan (``admm_dolfinx.admm.plan``) takes multigrid for the step 1 of a 3D body whose
factorisation would cost more than ``FACTOR_FLOPS_LIMIT`` operations. This script
measures where the two paths cross: Example 3's block on the half-ball (held by its
top face, the paper's contact model) on meshes from 3k to 158k dofs, and a held-out
kind, the same block of hexahedra. Each mesh is solved with ``step1="factorised"``
(MUMPS Cholesky) and with ``step1="iterative"`` (CG + GAMG, the inexact rule), one
after the other in one run, each timed from the solver's construction to its answer
(r*, the set-up and the iterations; assembly excluded), best of ``--repeat``
interleaved rounds. A path given explicitly skips the choice between them, which the
default makes first: ``default plan s`` times that choice apart (the mesh's bracket
of the factorisation's cost, and MUMPS's analysis where the bracket straddles the
limit).

Columns: dofs, contact nodes, ``MUMPS flops`` (its analysis's operation count for a
factorisation of A), the seconds and iterations of each path, ``multigrid /
factorised`` (below 1: multigrid is faster), the largest recomputed KKT residual of
each (both meet the tolerance 1e-6), ``u gap`` the relative difference of their
displacements, and what the default (``step1="auto"``) chose, on what basis and in how
many seconds.

    python benchmarks/step1_crossover.py            # nine meshes (about 7 min)
    python benchmarks/step1_crossover.py --quick    # two small meshes (smoke test)

Writes out_benchmarks/step1_crossover.csv.
"""

from __future__ import annotations

import argparse
import warnings
from pathlib import Path

from mpi4py import MPI
from scale_3d import LADDER, MODEL
from tables import print_and_save, select
from timing import best_of_rounds, timed

import admm_dolfinx
from admm_dolfinx.admm.plan import FACTOR_FLOPS_LIMIT, make_plan
from admm_dolfinx.linalg.factor_estimate import mumps_estimate
from admm_dolfinx.scenes import example3, example3_hexahedral


def _block(level, h_bottom=None, h_top=None):
    if h_bottom is None:
        return lambda: example3(level=level)
    # the ladder's proportion of the top face's element size to the bottom's
    h_top = 0.93 * h_bottom if h_top is None else h_top
    return lambda: example3(level=level, h_bottom=h_bottom, h_top=h_top)


#: name: the scene
CASES = {
    "level 1": _block(1),
    "13k": _block(3, 1.3),
    "level 2": _block(2),
    "25k": _block(3, 1.0),
    "40k": _block(3, 0.6),
    "76k": _block(3, 0.45),
    "158k": _block(*LADDER["158k"]),
    "hex 16": lambda: example3_hexahedral(cells=16),
    "hex 24": lambda: example3_hexahedral(cells=24),
}
QUICK = {"level 1": CASES["level 1"], "13k": CASES["13k"]}


def solve(problem, step1):
    """A function that solves the problem with this step 1 and returns the result."""

    def run():
        with admm_dolfinx.ADMMSolver(problem, step1=step1) as solver:
            return solver.solve()

    return run


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="two small meshes")
    parser.add_argument("--only", help="comma-separated case names")
    parser.add_argument("--repeat", type=int, default=2, help="interleaved rounds")
    parser.add_argument("--out", default="out_benchmarks")
    args = parser.parse_args()
    cases = select(parser, QUICK if args.quick else CASES, args.only)
    comm = MPI.COMM_WORLD
    root = comm.rank == 0
    if root:
        Path(args.out).mkdir(parents=True, exist_ok=True)
    with warnings.catch_warnings():  # compile every form once, untimed
        warnings.simplefilter("ignore")
        for scene in (example3(level=0), example3_hexahedral(cells=2)):
            for step1 in ("factorised", "iterative"):
                solve(scene.problem(contact_normal=MODEL), step1)()
    rows: list[dict] = []
    for name, build in cases.items():
        problem = build().problem(contact_normal=MODEL)
        estimate = mumps_estimate(problem.A)
        best = best_of_rounds(
            args.repeat,
            {step1: solve(problem, step1) for step1 in ("factorised", "iterative")},
            min_time=0.0,
        )
        (t_f, r_f), (t_i, r_i) = best["factorised"], best["iterative"]
        settings = admm_dolfinx.ADMMSettings.create()
        plan_s, plan = timed(lambda p=problem, s=settings: make_plan(p, s))
        gap = (r_i.u.x.petsc_vec - r_f.u.x.petsc_vec).norm() / r_f.u.x.petsc_vec.norm()
        rows.append(
            {
                "mesh": name,
                "dofs": problem.V.dofmap.index_map.size_global * 3,
                "contact nodes": problem.contact.num_global,
                "MUMPS flops": f"{estimate.flops:.3g}" if estimate else "–",
                "factorised s": f"{t_f:.3g}",
                "factorised its": r_f.iterations,
                "multigrid s": f"{t_i:.3g}",
                "multigrid its": r_i.iterations,
                "multigrid / factorised": f"{t_i / t_f:.2f}",
                "kkt factorised": f"{r_f.kkt.max():.1e}",
                "kkt multigrid": f"{r_i.kkt.max():.1e}",
                "u gap": f"{gap:.1e}",
                f"default (limit {FACTOR_FLOPS_LIMIT:.0e})": f"{plan.step1} ({plan.step1_basis})",
                "default plan s": f"{plan_s:.2g}",
            }
        )
        assert r_f.converged and r_i.converged, name
        if root:
            print_and_save(rows, Path(args.out) / "step1_crossover.csv")


if __name__ == "__main__":
    main()
