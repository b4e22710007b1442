"""2D under refinement: the default ADMM against a plain factorised solve, to h = 1/512.

Example 1 of the paper (gmsh's unstructured mesh) at h = 1/64 … 1/512 (1.2M dofs,
1024 contact nodes). For each mesh, in one process, one after the other:

* ``plain``: one elastic solve A u = f of the same matrix (no contact) with the
  default step-1 solver (MUMPS Cholesky, the 2D ordering): factorisation and one
  substitution;
* ``default``: ``ADMMSolver(problem).solve()``: the plan, r*, the factorisation,
  the iterations with active-set polishing, the final KKT check;
* ``condensed AMD``, ``condensed METIS``: the condensed factorisation (A with the
  Schur complement S_C onto the contact dofs, what the default factorises in 2D)
  under each of MUMPS's orderings; the default takes METIS from
  ``CONDENSED_METIS_DOFS`` dofs on (:mod:`admm_dolfinx.operators.condensed`).

Columns: seconds (``mesh s`` is not in ``total``), ADMM iterations, polishing
attempts and rounds (primal-dual active-set corrections; a walk stopped by its round
limit is resumed by the next attempt, :mod:`admm_dolfinx.admm.active_set`), the
recomputed KKT residual, and ``default/plain``, the ratio of the two totals.

    python benchmarks/scale_2d.py            # h = 1/64 … 1/512 (about 10 minutes)
    python benchmarks/scale_2d.py --quick    # h = 1/32, 1/64 (smoke test)

Writes out_benchmarks/scale_2d.csv.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

SIZES = (64, 128, 256, 512)
QUICK = (32, 64)
#: MUMPS orderings (ICNTL(7)) the condensed factorisation is timed under.
ORDERINGS = {"AMD": 0, "METIS": 5}


def _plain_solve(problem) -> dict:
    """The factorised elastic solve of A u = f: seconds of each phase."""
    from admm_dolfinx.linalg.petsc import check_solve, create_factor_solver

    b = problem.create_vector()
    problem.assemble_rhs(0.0, b)
    x = b.duplicate()
    matrix = problem.A.duplicate(copy=True)
    t0 = time.perf_counter()
    ksp = create_factor_solver(matrix, "plain_", None, problem.gdim)
    ksp.setUp()
    factorisation = time.perf_counter() - t0
    t0 = time.perf_counter()
    ksp.solve(b, x)
    check_solve(ksp, "the plain solve")
    solve = time.perf_counter() - t0
    for obj in (ksp, matrix, b, x):
        obj.destroy()
    return {"factorisation": factorisation, "solve": solve}


def _condensed_factorisation(problem, ordering: int) -> float:
    """Seconds of the condensed factorisation (S_C onto Γ_C) under one MUMPS ordering."""
    from admm_dolfinx.operators.condensed import CondensedOperator

    operator = CondensedOperator(problem, f"ordering{ordering}_", {"mat_mumps_icntl_7": ordering})
    try:
        operator.set_penalty(1.0)
        return operator.timings["factorization"]
    finally:
        operator.destroy()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="two small meshes")
    parser.add_argument("--out", default="out_benchmarks")
    args = parser.parse_args()
    from mpi4py import MPI
    from tables import print_and_save

    import admm_dolfinx
    from admm_dolfinx.scenes import example1

    comm = MPI.COMM_WORLD
    Path(args.out).mkdir(parents=True, exist_ok=True)
    rows = []
    for n in QUICK if args.quick else SIZES:
        t0 = time.perf_counter()
        scene = example1(comm, h=1 / n)
        mesh_time = time.perf_counter() - t0
        t0 = time.perf_counter()
        problem = scene.problem()
        assembly = time.perf_counter() - t0
        plain = _plain_solve(problem)
        orderings = {name: _condensed_factorisation(problem, k) for name, k in ORDERINGS.items()}
        t0 = time.perf_counter()
        with admm_dolfinx.ADMMSolver(problem) as solver:
            plan = solver.plan
            result = solver.solve()
        default = time.perf_counter() - t0
        polish = result.polish
        row = {
            "h": f"1/{n}",
            "dofs": problem.V.dofmap.index_map.size_global * 2,
            "contact nodes": problem.contact.num_global,
            "mesh s": mesh_time,
            "assembly": assembly,
            "plain factorisation": plain["factorisation"],
            "plain solve": plain["solve"],
            "plain total": assembly + plain["factorisation"] + plain["solve"],
            **{f"condensed {name}": seconds for name, seconds in orderings.items()},
            "step 1": plan.step1,
            "r*": result.timings.penalty,
            "factorisation": result.timings.operator + result.timings.factorization,
            "iterations s": result.timings.iterations,
            "default total": assembly + default,
            "ADMM its": result.iterations,
            "polish attempts": polish.attempts if polish else "–",
            "polish rounds": polish.rounds if polish else "–",
            "converged": result.converged,
            "kkt": f"{result.kkt.max():.1e}",
        }
        row["default/plain"] = row["default total"] / row["plain total"]
        rows.append({k: (f"{v:.3g}" if isinstance(v, float) else v) for k, v in row.items()})
        if comm.rank == 0:
            print(rows[-1], flush=True)
    if comm.rank == 0:
        print_and_save(rows, Path(args.out) / "scale_2d.csv")


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import dolfinx_solver  # noqa: F401  (before dolfinx, petsc4py)

    main()
