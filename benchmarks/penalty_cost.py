"""Cost of the automatic penalty r* against the ADMM solve it serves.

For each problem, in one run and side by side:

* ``estimate``: ``estimate_penalty(problem)`` standalone (its own factorisations: in
  2D the condensed factorisation of A, in 3D the iterative method's);
* ``admm``: ``ADMMSolver(problem, penalty=r*, mode="paper").solve()`` standalone
  (its factorisation of A + r*NᵀMN included), and the same in accelerated mode
  (α = 1.6, Anderson 5, without polishing: the same iteration at both penalties),
  all in the paper's metric r M (the 3D default's surface metric adds β and μ_max to
  r*: ``benchmarks/surface_metric.py`` times it) and with a factorised step 1 (in 3D
  the plan may take multigrid: ``benchmarks/scale_3d.py`` times that path);
* ``auto``: the same two with ``penalty="auto"`` (the default), where r* and the ADMM
  share factorisations: in 2D one condensed factorisation serves both, in 3D the
  symbolic one is shared.

The overhead of r* is (auto − admm)/admm: what choosing r automatically adds to a
solve at a given r. The r* time inside the auto solve (``r* in auto``) and the
estimate's own breakdown are those of the fastest round. Everything is printed as a
markdown table and written to ``out_benchmarks/penalty_cost.csv``. Each time is the
best of ``--repeat`` interleaved rounds (one call of each per round), and of more
rounds while they take under 10 s in all (the machines are noisy). Run:

    python benchmarks/penalty_cost.py            # Example 1 h=1/64 … 1/256; Example 3 level 3
    python benchmarks/penalty_cost.py --quick    # small sizes, for a smoke test
"""

from __future__ import annotations

import argparse
from pathlib import Path

from mpi4py import MPI
from tables import print_and_save
from timing import best_of_rounds

import admm_dolfinx
from admm_dolfinx.scenes.library import example1, example3

#: The paper's contact model (along the body's normal): the README's tables of this
#: script were measured in it, and SNES VI's bounds apply to Example 3 only in it.
MODEL = "body"


def _breakdown(est) -> str:
    d = est.details
    if d["method"] == "dense":
        return (
            f"condensed factorisation {d['time_factorization']:.3g} + dense {d['time_dense']:.2g}"
        )
    text = f"λ_min {d['time_min']:.3g} + λ_max {d['time_max']:.3g}"
    if "time_multigrid_setup" in d:
        text += f" (AMG setup {d['time_multigrid_setup']:.3g}, LOBPCG {d['lobpcg_iterations']} its)"
    return text


def measure(name, scene, repeat):
    problem = scene.problem(contact_normal=MODEL)
    est = admm_dolfinx.estimate_penalty(problem)  # r*, for the solves at a given r

    def estimate():
        return admm_dolfinx.estimate_penalty(problem)

    def solver(mode, penalty):
        def run():
            # no polishing: it needs S_C, which only the auto solve would have at hand;
            # a factorised step 1 at both penalties (the 3D plan may take multigrid,
            # whose inexact solves would make the two iterations differ)
            with admm_dolfinx.ADMMSolver(
                problem,
                penalty=penalty,
                mode=mode,
                polish=False,
                step1="factorised",
                expert={"penalty_metric": "mass"},
            ) as admm:
                return admm.solve()

        return run

    best = best_of_rounds(
        repeat,
        {
            "estimate": estimate,
            "admm": solver("paper", est.r),
            "auto": solver("paper", "auto"),
            "fast": solver("accelerated", est.r),
            "auto fast": solver("accelerated", "auto"),
        },
        min_time=10.0,  # sub-second solves vary by 50 % here: take many rounds of them
    )
    t_est, est = best["estimate"]
    t_admm, res = best["admm"]
    t_auto, res_auto = best["auto"]
    t_fast, res_fast = best["fast"]
    t_auto_fast, res_auto_fast = best["auto fast"]
    row = {
        "problem": name,
        "nodes": scene.num_nodes,
        "m": problem.num_contact_nodes,
        "method": est.details["method"],
        "r*": f"{est.r:.5g}",
        "t_estimate": f"{t_est:.3f}",
        "estimate breakdown": _breakdown(est),
        "t_admm": f"{t_admm:.3f}",
        "iterations": res.iterations,
        "t_factorization": f"{res.timings['factorization']:.3f}",
        "estimate/admm": f"{t_est / t_admm:.2f}",
        "t_auto": f"{t_auto:.3f}",
        "r* in auto": f"{res_auto.timings['penalty']:.3f}",
        "(auto-admm)/admm": f"{(t_auto - t_admm) / t_admm:.2f}",
        "t_admm accelerated": f"{t_fast:.3f}",
        "accelerated iterations": res_fast.iterations,
        "t_auto accelerated": f"{t_auto_fast:.3f}",
        "(auto-admm)/admm accelerated": f"{(t_auto_fast - t_fast) / t_fast:.2f}",
    }
    # the same r*, so the same iterations (a condensed solve differs by round-off only)
    for auto, fixed in ((res_auto, res), (res_auto_fast, res_fast)):
        if auto.iterations != fixed.iterations:
            raise RuntimeError(
                f"{name}: {auto.iterations} iterations at r = {auto.penalty:.8g} (auto) "
                f"against {fixed.iterations} at r* = {fixed.penalty:.8g}"
            )
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
            ("example1 h=1/128", lambda: example1(h=1 / 128)),
            ("example1 h=1/256", lambda: example1(h=1 / 256)),
            ("example3 level 3", lambda: example3(level=3)),
        ]
    )
    rows = [measure(name, build(), args.repeat) for name, build in cases]
    if MPI.COMM_WORLD.rank == 0:
        print_and_save(rows, Path(args.out) / "penalty_cost.csv")


if __name__ == "__main__":
    main()
