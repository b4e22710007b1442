"""MUMPS fill-reducing orderings for the factorisation of A + r*NᵀMN, 2D against 3D.

The ADMM factorises A + r*NᵀMN once (MUMPS Cholesky, ``ICNTL(7)`` = 7: MUMPS picks
the ordering; the table says which) and then spends one forward/backward substitution per
iteration. For each mesh and ordering this measures, side by side in one run
(interleaved rounds, best of each), the factorisation (analysis included), and prints
each ordering's factorisation time relative to the default, with the default's
factorisation and substitution times. Choose an
ordering with ``ADMMSolver(problem, petsc_options={"mat_mumps_icntl_7": k})``.

    python benchmarks/orderings.py            # Example 1 h=1/64..1/256, Hertz, Example 3
    python benchmarks/orderings.py --quick    # small meshes, for a smoke test

Writes out_benchmarks/orderings.csv.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from mpi4py import MPI
from tables import print_and_save
from timing import best_of_rounds

import admm_dolfinx
from admm_dolfinx.operators.penalised import PenalisedOperator
from admm_dolfinx.scenes.library import example1, example2, example3

#: The paper's contact model (along the body's normal): the README's tables of this
#: script were measured in it, and SNES VI's bounds apply to Example 3 only in it.
MODEL = "body"

#: MUMPS ICNTL(7) values: name -> value (7 = automatic, the package default).
ORDERINGS = {"auto": 7, "AMD": 0, "AMF": 2, "METIS": 5, "SCOTCH": 3, "PORD": 4}


#: MUMPS's ordering codes (INFOG(7): the ordering it actually used).
ORDERING_NAMES = {0: "AMD", 2: "AMF", 3: "SCOTCH", 4: "PORD", 5: "METIS", 6: "QAMD"}


def factorise_and_solve(problem, r, ordering):
    """(factorisation s, substitution s, ordering used) with the given ICNTL(7)."""
    op = PenalisedOperator(problem, "ordering_", {"mat_mumps_icntl_7": ordering})
    b, x = problem.create_vector(), problem.create_vector()
    try:
        MPI.COMM_WORLD.Barrier()
        t0 = time.perf_counter()
        op.set_penalty(r)
        t_fact = time.perf_counter() - t0
        used = op.ksp.getPC().getFactorMatrix().getMumpsInfog(7)
        problem.assemble_rhs(r, b)
        t0 = time.perf_counter()
        op.solve(b, x)
        t_solve = time.perf_counter() - t0
    finally:
        for obj in (b, x, op):
            obj.destroy()
    slowest = MPI.COMM_WORLD.allreduce([t_fact, t_solve], op=MPI.MAX)
    return slowest[0], slowest[1], used


def measure(name, scene, repeat):
    problem = scene.problem(contact_normal=MODEL)
    r = admm_dolfinx.estimate_penalty(problem).r
    functions = {
        label: (lambda k=k: factorise_and_solve(problem, r, k)) for label, k in ORDERINGS.items()
    }
    # best_of_rounds times each call; the factorisation time is returned inside it
    best = best_of_rounds(repeat, functions, min_time=0.0)
    t_auto, t_solve, used = best["auto"][1]
    row = {
        "mesh": name,
        "dofs": problem.A.getSize()[0],
        "auto chose": ORDERING_NAMES.get(used, str(used)),
        "auto factorisation [s]": f"{t_auto:.3g}",
        "substitution [s]": f"{t_solve:.3g}",
    }
    for label in ORDERINGS:
        if label != "auto":
            row[f"{label} / auto"] = f"{best[label][1][0] / t_auto:.2f}"
    rows = [row]
    problem.destroy()
    return rows


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small meshes (smoke test)")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--out", default="out_benchmarks")
    args = parser.parse_args()
    cases = (
        [
            ("example1 h=1/32", lambda: example1(h=1 / 32)),
            ("example3 level 1", lambda: example3(level=1)),
        ]
        if args.quick
        else [
            ("example1 h=1/64", lambda: example1(h=1 / 64)),
            ("example1 h=1/128", lambda: example1(h=1 / 128)),
            ("example1 h=1/256", lambda: example1(h=1 / 256)),
            ("hertz level 3", lambda: example2(level=3)),
            ("example3 level 1", lambda: example3(level=1)),
            ("example3 level 2", lambda: example3(level=2)),
            ("example3 level 3", lambda: example3(level=3)),
        ]
    )
    rows = []
    for name, build in cases:
        repeat = 1 if "level 3" in name and "example3" in name else args.repeat
        rows += measure(name, build(), repeat)
    if MPI.COMM_WORLD.rank == 0:
        print_and_save(rows, Path(args.out) / "orderings.csv")


if __name__ == "__main__":
    main()
