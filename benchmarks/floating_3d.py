"""A body that the contact alone holds, on the multigrid path: polished by multigrid or not.

Past the plan's factorisation limits (``FACTOR_FLOPS_LIMIT``, or
``INVERSE_MAX_CONTACT_NODES`` for polishing from the factors) a floating body's step 1
is CG + GAMG. Unpolished, its
ADMM builds the contact zone a few nodes per iteration; the default polishes it by
the active-set walk with multigrid solves (:mod:`admm_dolfinx.admm.polish_sparse`).
For each mesh, in one run, one after the other:

* ``multigrid``: ``ADMMSolver(problem, step1="iterative")``: the default past the
  limits (``polish sparse``);
* ``plain steps``: the same with the walk's plain primal-dual steps
  (``admm_dolfinx.admm.polish_sparse.SHED_FACTOR`` set to 1 for it): what the walk
  did before it shed twice the rim of a guess too large;
* ``no polish``: the same with ``polish=False``: what the default did before;
* ``default``: ``ADMMSolver(problem)``, the plan's own choice (below the limits a
  factorised step 1, polished from its factors), on the meshes up to
  ``--default-limit`` dofs;
* ``factorised``: ``ADMMSolver(problem, step1="factorised")``, on the same meshes:
  the factorised step 1, polished from its factors where ``INVERSE_MAX_CONTACT_NODES``
  allows, which the default kept for floating bodies up to 10¹² operations before
  the multigrid path polished;
* ``plain``: one elastic solve of the same size: A + rNᵀMN (the body held along the
  normal on all of Γ_C by the penalty, at the multigrid run's r), CG + GAMG with the
  rigid body modes to ``ksp_rtol = 1e-8``, set-up included.

The scenes are the Hertz quarter-ball (``hertz_sphere``, a = R/20) at levels 2-4 and,
held out (the polishing rules were not tuned on it), the same ball under the load
that makes its contact zone three times as wide (a = R/6.7) at levels 2-4. Level 4
is past ``INVERSE_MAX_CONTACT_NODES``, so there the plan itself takes this path.

Columns: wall seconds (the slowest rank's; assembly excluded, everything from the
solver's construction to its answer included), CPU seconds (process time summed over
the ranks), their ratio to the plain solve's, where the wall time went (rank 0's
``result.timings``, each in plain solves: r* with its λ_max and λ_min, the set-up of
step 1's operator and multigrid, the walk, and the rest of the iterations with the
final KKT check), ADMM iterations, the walk's rounds and Krylov iterations, the
largest relative KKT residual, ‖u − u_np‖/‖u_np‖ against the
unpolished answer, and the machine's 1-minute load average when the mesh's rows
started.

    python benchmarks/floating_3d.py            # both scenes, levels 2-4 (about 30 min)
    python benchmarks/floating_3d.py --quick    # level 1 of the Hertz ball (smoke test)
    python benchmarks/floating_3d.py --only "hertz level 3"

Writes out_benchmarks/floating_3d.csv.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

from mpi4py import MPI
from polish_3d import relative_difference
from tables import print_and_save, select

import admm_dolfinx.admm.polish_sparse as polish_sparse
from admm_dolfinx import ADMMSolver
from admm_dolfinx.linalg.petsc import iterative_options
from admm_dolfinx.operators.penalised import IterativeOperator
from admm_dolfinx.scenes.library import hertz_sphere

#: The held-out scene's contact radius (the Hertz ball's is 0.4 = R/20).
WIDE_HALF_WIDTH = 1.2
CASES = {
    **{f"hertz level {k}": {"level": k} for k in (2, 3, 4)},
    **{f"wide level {k}": {"level": k, "half_width": WIDE_HALF_WIDTH} for k in (2, 3, 4)},
}
QUICK = {"hertz level 1": {"level": 1}}
#: The plain solve's tolerance (the scale_3d ladder's).
PLAIN_RTOL = 1e-8


def measured(fn):
    """(wall seconds of the slowest rank, CPU seconds summed over ranks, value)."""
    comm = MPI.COMM_WORLD
    comm.Barrier()
    wall, cpu = time.perf_counter(), time.process_time()
    value = fn()
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    return comm.allreduce(wall, op=MPI.MAX), comm.allreduce(cpu, op=MPI.SUM), value


def contact_solve(problem, **settings):
    """The result of one solve, and its plan's step 1 and polish."""
    with ADMMSolver(problem, **settings) as solver:
        result = solver.solve()
        return result, f"{solver.plan.step1}, polish {solver.plan.polish}"


def plain_steps_solve(problem):
    """The multigrid path's solve with the walk's plain primal-dual steps."""
    shed = polish_sparse.SHED_FACTOR
    polish_sparse.SHED_FACTOR = 1.0
    try:
        return contact_solve(problem, step1="iterative")
    finally:
        polish_sparse.SHED_FACTOR = shed


def plain_solve(problem, r):
    """Krylov iterations of one CG + GAMG solve of A + rNᵀMN, set-up included."""
    # PETSc's default stopping test (preconditioned residual), as every page's plain solve
    options = {**iterative_options(None), "ksp_norm_type": "preconditioned"}
    operator = IterativeOperator(problem, "floating_plain_", options)
    b, x = problem.create_vector(), problem.create_vector()
    try:
        operator.set_penalty(r)
        operator.set_tolerance(PLAIN_RTOL)
        problem.load_vector().copy(b)
        x.set(0.0)
        operator.solve(b, x)
        return operator.last_iterations
    finally:
        for obj in (operator, b, x):
            obj.destroy()


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="level 1 of the Hertz ball")
    parser.add_argument("--only", help="the meshes whose name contains this")
    parser.add_argument(
        "--default-limit",
        type=float,
        default=1e5,
        help="run the plan's default and the factorised path on meshes up to this many dofs",
    )
    parser.add_argument("--out", default="out_benchmarks")
    args = parser.parse_args()
    comm = MPI.COMM_WORLD
    cases = select(parser, QUICK if args.quick else CASES, args.only)
    rows = []
    for name, kwargs in cases.items():
        load = os.getloadavg()[0]
        problem = hertz_sphere(comm, **kwargs).problem()
        dofs = problem.A.getSize()[0]
        runs = {
            "multigrid": measured(lambda p=problem: contact_solve(p, step1="iterative")),
            "plain steps": measured(lambda p=problem: plain_steps_solve(p)),
            "no polish": measured(
                lambda p=problem: contact_solve(p, step1="iterative", polish=False)
            ),
        }
        if dofs <= args.default_limit:
            runs["default"] = measured(lambda p=problem: contact_solve(p))
            runs["factorised"] = measured(lambda p=problem: contact_solve(p, step1="factorised"))
        r = runs["multigrid"][2][0].penalty
        plain = measured(lambda p=problem, r=r: plain_solve(p, r))
        reference = runs["no polish"][2][0]
        common = {"mesh": name, "dofs": dofs, "m": problem.num_contact_nodes, "load": f"{load:.2f}"}
        rows.append(
            common
            | {
                "config": "plain",
                "its": f"{plain[2]} CG",
                "wall [s]": f"{plain[0]:.3g}",
                "CPU [s]": f"{plain[1]:.3g}",
            }
        )
        for label, (wall, cpu, (result, plan)) in runs.items():
            polish = result.polish
            t, walk = result.timings, polish.time if polish else 0.0
            phases = (t.penalty, t.operator + t.factorization, walk, t.iterations - walk + t.kkt)
            same = label == "no polish"
            difference = relative_difference(problem, result.u.x.array, reference.u.x.array)
            rows.append(
                common
                | {
                    "config": label,
                    "plan": plan,
                    "its": result.iterations,
                    "rounds": polish.rounds if polish else "–",
                    "walk Krylov its": polish.krylov_iterations if polish else "–",
                    "wall [s]": f"{wall:.3g}",
                    "CPU [s]": f"{cpu:.3g}",
                    "wall / plain": f"{wall / plain[0]:.2f}",
                    "CPU / plain": f"{cpu / plain[1]:.2f}",
                    "r* / set-up / walk / rest ÷ plain": " / ".join(
                        f"{x / plain[0]:.1f}" for x in phases
                    ),
                    "KKT": f"{result.kkt.max():.1e}",
                    "‖u − u_np‖/‖u_np‖": "–" if same else f"{difference:.1e}",
                }
            )
        if comm.rank == 0:
            print(
                f"{name}: multigrid {runs['multigrid'][0]:.3g} s, no polish "
                f"{runs['no polish'][0]:.3g} s, plain {plain[0]:.3g} s",
                flush=True,
            )
        problem.destroy()
    if comm.rank == 0:
        print_and_save(rows, Path(args.out) / "floating_3d.csv")


if __name__ == "__main__":
    main()
