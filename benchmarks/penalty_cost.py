"""Cost of the automatic penalty r* against the ADMM solve it serves.

For each problem, in one run and side by side:

* ``estimate``: ``estimate_penalty(problem)`` standalone (its own factorisations);
* ``admm``: ``ADMMSolver(problem, penalty=r*, mode="paper").solve()`` standalone
  (factorisation of A + r*NᵀMN included), and the same with the accelerated default;
* ``auto``: ``ADMMSolver(problem, mode="paper").solve()`` - penalty="auto", where the
  estimate shares the symbolic factorisation with the ADMM.

The estimate's own breakdown (λ_min on layers, λ_max, and the algebraic-multigrid
setup inside λ_max) is that of its fastest round. The ratios estimate/admm and
(auto − admm)/admm are printed as a markdown table and
written to ``out_benchmarks/penalty_cost.csv``. Each time is the best of
``--repeat`` interleaved rounds (one call of each per round), and of more rounds while
they take under 2 s in all (the machines are noisy). Run:

    python benchmarks/penalty_cost.py            # Example 1 h=1/64, Example 3 level 3
    python benchmarks/penalty_cost.py --quick    # small sizes, for a smoke test
"""

from __future__ import annotations

import argparse
from pathlib import Path

from mpi4py import MPI
from tables import print_and_save
from timing import best_of_rounds

import admm_dolfinx
from admm_dolfinx.scenes import example1, example3


def measure(name, scene, repeat):
    problem = scene.problem()
    est = admm_dolfinx.estimate_penalty(problem)  # r*, for the solves at a given r

    def estimate():
        return admm_dolfinx.estimate_penalty(problem)

    def admm():
        with admm_dolfinx.ADMMSolver(problem, penalty=est.r, mode="paper") as solver:
            return solver.solve()

    def admm_fast():
        with admm_dolfinx.ADMMSolver(problem, penalty=est.r) as solver:
            return solver.solve()

    def auto():
        with admm_dolfinx.ADMMSolver(problem, mode="paper") as solver:
            return solver.solve()

    best = best_of_rounds(
        repeat, {"estimate": estimate, "admm": admm, "fast": admm_fast, "auto": auto}
    )
    t_est, est = best["estimate"]
    t_admm, res = best["admm"]
    t_fast, res_fast = best["fast"]
    t_auto = best["auto"][0]
    row = {
        "problem": name,
        "nodes": scene.num_nodes,
        "m": problem.num_contact_nodes,
        "r*": f"{est.r:.5g}",
        "solves": est.solves,
        "t_estimate": f"{t_est:.3f}",
        "t_lambda_min": f"{est.details['time_min']:.3f}",
        "t_lambda_max": f"{est.details['time_max']:.3f}",
        "t_multigrid_setup": f"{est.details.get('time_multigrid_setup', 0.0):.3f}",
        "lobpcg_iterations": est.details.get("lobpcg_iterations", "-"),
        "t_admm": f"{t_admm:.3f}",
        "admm_iterations": res.iterations,
        "t_factorization": f"{res.timings['factorization']:.3f}",
        "estimate/admm": f"{t_est / t_admm:.2f}",
        "t_admm accelerated": f"{t_fast:.3f}",
        "accelerated iterations": res_fast.iterations,
        "estimate/accelerated": f"{t_est / t_fast:.2f}",
        "t_auto": f"{t_auto:.3f}",
        "(auto-admm)/admm": f"{(t_auto - t_admm) / t_admm:.2f}",
    }
    problem.destroy()
    return row


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small sizes (smoke test)")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--out", default="out_benchmarks")
    args = parser.parse_args()
    cases = (
        [
            ("example1 h=1/16", lambda: example1(h=1 / 16)),
            ("example3 level 1", lambda: example3(level=1)),
        ]
        if args.quick
        else [
            ("example1 h=1/64", lambda: example1(h=1 / 64)),
            ("example3 level 3", lambda: example3(level=3)),
        ]
    )
    rows = [measure(name, build(), args.repeat) for name, build in cases]
    if MPI.COMM_WORLD.rank == 0:
        print_and_save(rows, Path(args.out) / "penalty_cost.csv")


if __name__ == "__main__":
    main()
